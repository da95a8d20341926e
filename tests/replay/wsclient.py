"""tests/replay/wsclient.py - a small RFC 6455 websocket client on the
standard library, for the replayed push sessions (replay.py's WS lines).

It checks what a browser checks of the server: the 101, the
Sec-WebSocket-Accept value, unmasked server frames with no reserved bits.
Messages come back joined from their fragments; pings are answered; a close
ends the stream (recv returns None).  SockJS's websocket transport
(sockjs=True) is unwrapped: the "o" open frame and "h" heartbeats are
skipped, each 'a["..."]' frame yields its messages, and sends are wrapped
as '["..."]'.
"""
import base64, hashlib, json, os, socket, struct, time

GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


class WsError(Exception):
    pass


class Ws:
    def __init__(self, url, path, headers=None, sockjs=False, timeout=30):
        host, _, port = url.split("//", 1)[1].rstrip("/").partition(":")
        self.sock = socket.create_connection((host, int(port or 80)), timeout=timeout)
        self.sockjs = sockjs
        self.pending = []  # messages of a SockJS frame not handed out yet
        self.opened = False  # SockJS "o" seen
        key = base64.b64encode(os.urandom(16)).decode()
        hdrs = {"Host": "%s:%s" % (host, port), "Upgrade": "websocket", "Connection": "Upgrade",
                "Sec-WebSocket-Key": key, "Sec-WebSocket-Version": "13"}
        hdrs.update(headers or {})
        lines = ["GET %s HTTP/1.1" % path] + ["%s: %s" % kv for kv in hdrs.items()]
        self.sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise WsError("connection closed during the handshake")
            self.buf += chunk
        head, self.buf = self.buf.split(b"\r\n\r\n", 1)
        status = head.split(b"\r\n")[0].decode("latin-1")
        self.status = int(status.split()[1])
        if self.status != 101:
            raise WsError("handshake answered %r" % status)
        want = base64.b64encode(hashlib.sha1((key + GUID).encode()).digest()).decode()
        hdrs = {k.strip().lower(): v.strip() for k, _, v in
                (l.decode("latin-1").partition(":") for l in head.split(b"\r\n")[1:])}
        if hdrs.get("sec-websocket-accept") != want:
            raise WsError("Sec-WebSocket-Accept %r, not %r" % (hdrs.get("sec-websocket-accept"), want))
        if hdrs.get("upgrade", "").lower() != "websocket":
            raise WsError("Upgrade header %r" % hdrs.get("upgrade"))

    def _read(self, n, deadline):
        while len(self.buf) < n:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                return None
            if not chunk:
                raise WsError("connection closed")
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def send_frame(self, op, payload):
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | op])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 65536:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def send(self, text):
        if self.sockjs:
            text = json.dumps([text])
        self.send_frame(0x1, text.encode())

    def _frame(self, deadline):
        """One whole message (op, payload), None on timeout."""
        parts, first = [], None
        while True:
            h = self._read(2, deadline)
            if h is None:
                return None
            if h[0] & 0x70 or h[1] & 0x80:
                raise WsError("server frame with reserved bits or a mask: %r" % h)
            op, n = h[0] & 0x0f, h[1] & 0x7f
            if n == 126:
                n = struct.unpack(">H", self._read(2, deadline + 5))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8, deadline + 5))[0]
            payload = self._read(n, deadline + 5) if n else b""
            if op == 0x9:
                self.send_frame(0xa, payload)
                continue
            if op == 0xa:
                continue
            if op == 0x8:
                return (op, payload)
            parts.append(payload)
            first = first if first is not None else op
            if h[0] & 0x80:
                return (first, b"".join(parts))

    def recv(self, timeout):
        """The next message's text; None once the server closed; raises socket.timeout."""
        deadline = time.monotonic() + timeout
        while not self.pending:
            f = self._frame(deadline)
            if f is None:
                raise socket.timeout("no message in %.0f s" % timeout)
            op, payload = f
            if op == 0x8:
                self.close_code = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else None
                return None
            text = payload.decode("utf-8")
            if not self.sockjs:
                return text
            if not self.opened and text != "o":
                raise WsError("SockJS frame %r before the open frame" % text[:80])
            if text == "o":
                self.opened = True
            elif text == "h":
                continue
            elif text.startswith("a"):
                self.pending += json.loads(text[1:])
            elif text.startswith("c"):
                self.close_code = json.loads(text[1:])[0]
                return None
            else:
                raise WsError("SockJS frame %r" % text[:80])
        return self.pending.pop(0)

    def close(self):
        try:
            self.send_frame(0x8, struct.pack(">H", 1000))
        except OSError:
            pass
        self.sock.close()
