#!/usr/bin/python3
"""tests/replay/bambu_replay.py - replay one recorded Bambu LAN client
session (tests/replay/clients/bambu-CLIENT.txt) against a simulated Bambu
printer: MQTT 3.1.1 over TLS to the printer's broker and implicit FTPS to
its storage, as the printers serve them, with the standard library only.

usage: bambu_replay.py HOST MQTT_PORT FTPS_PORT SERIAL ACCESS_CODE SESSION_FILE

Certificates are not checked (the printers' are self-signed: every LAN
client turns the check off).  {SERIAL} in a line stands for the serial.
Lines (quoted as a shell would; # comments):

  MQTT CONNECT [pass=TEXT] -> CODE   connect as bblp with the access code (or TEXT);
                                     CODE is CONNACK's return code (0 accepted, 5 refused)
  MQTT SUB TOPIC                     subscribe (QoS 0) and wait for SUBACK
  MQTT PUB TOPIC TEXT                publish TEXT (QoS 0)
  MQTT RECV [SECONDS] CHECK...       skip messages until one (JSON) passes the checks
  FTP LOGIN [pass=TEXT] -> CODE      connect (implicit TLS), USER bblp, PASS; the reply's code
  FTP PROT_P -> CODE                 PBSZ 0 and PROT P (data connections in TLS)
  FTP CMD TEXT -> CODE               one command, its reply's code
  FTP STOR NAME BYTES -> CODE        upload BYTES bytes of G-code as NAME (TLS session reused)
  FTP LIST [ARG] -> CODE [has=NAME]  LIST over a data connection; NAME must be in it
  FTP QUIT

CHECKs are replay.py's (a.b=VALUE, a.b:TYPE, !a.b ...).  The first failing
line ends the run with its file and line number; exit status 1.
"""
import ftplib, io, json, shlex, socket, ssl, struct, sys, time

import replay


def tls():
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    return ctx


# ---- MQTT 3.1.1, the few packets a LAN client sends ----

def varlen(n):
    out = b""
    while True:
        d, n = n % 128, n // 128
        out += bytes([d | (0x80 if n else 0)])
        if not n:
            return out


def mstr(s):
    b = s.encode()
    return struct.pack(">H", len(b)) + b


class Mqtt:
    def __init__(self, host, port, password):
        raw = socket.create_connection((host, port), timeout=30)
        self.sock = tls().wrap_socket(raw)
        body = mstr("MQTT") + bytes([4, 0xC2]) + struct.pack(">H", 60) + \
            mstr("replay-%d" % time.monotonic_ns()) + mstr("bblp") + mstr(password)
        self.sock.sendall(bytes([0x10]) + varlen(len(body)) + body)
        kind, data = self.packet(30)
        self.connack = data[1] if kind == 0x20 and len(data) == 2 else -1

    def exact(self, n):
        b = b""
        while len(b) < n:
            k = self.sock.recv(n - len(b))
            if not k:
                raise EOFError("the broker closed the connection")
            b += k
        return b

    def packet(self, secs):
        self.sock.settimeout(secs)
        head = self.exact(1)[0]
        n, mul = 0, 1
        while True:
            d = self.exact(1)[0]
            n += (d & 0x7F) * mul
            mul *= 128
            if not d & 0x80:
                break
        return head & 0xF0, self.exact(n)

    def subscribe(self, topic):
        body = struct.pack(">H", 1) + mstr(topic) + b"\x00"
        self.sock.sendall(bytes([0x82]) + varlen(len(body)) + body)
        end = time.monotonic() + 30
        while time.monotonic() < end:
            kind, data = self.packet(max(0.1, end - time.monotonic()))
            if kind == 0x90:
                return data[2:] == b"\x00"
        return False

    def publish(self, topic, text):
        body = mstr(topic) + text.encode()
        self.sock.sendall(bytes([0x30]) + varlen(len(body)) + body)

    def message(self, secs):
        """The next PUBLISH's payload, None when secs pass."""
        end = time.monotonic() + secs
        while time.monotonic() < end:
            try:
                kind, data = self.packet(max(0.05, end - time.monotonic()))
            except socket.timeout:
                return None
            if kind == 0x30:
                tlen = struct.unpack(">H", data[:2])[0]
                return data[2 + tlen:]
        return None


# ---- implicit FTPS with the control connection's TLS session reused ----

class Ftps(ftplib.FTP_TLS):
    def connect(self, host, port):
        self.host, self.port = host, port
        self.sock = self.context.wrap_socket(socket.create_connection((host, port), 30),
                                             server_hostname=host)
        self.af = self.sock.family
        self.file = self.sock.makefile("r", encoding=self.encoding)
        self.welcome = self.getresp()
        return self.welcome

    def ntransfercmd(self, cmd, rest=None):
        conn, size = ftplib.FTP.ntransfercmd(self, cmd, rest)
        if self._prot_p:  # vsftpd's require_ssl_reuse: the control connection's session
            conn = self.context.wrap_socket(conn, server_hostname=self.host,
                                            session=self.sock.session)
        return conn, size


def code_of(fn):
    try:
        return int(str(fn())[:3])
    except ftplib.all_errors as e:
        return int(str(e)[:3]) if str(e)[:3].isdigit() else -1


class Session:
    def __init__(self, host, mport, fport, serial, code):
        self.host, self.mport, self.fport, self.serial, self.code = host, mport, fport, serial, code
        self.mqtt = self.ftp = None

    def opt(self, opts, name, default):
        for o in opts:
            if o.startswith(name + "="):
                return o[len(name) + 1:]
        return default

    def mqtt_line(self, verb, rest):
        if verb == "CONNECT":
            arrow = rest.index("->")
            self.mqtt = Mqtt(self.host, self.mport, self.opt(rest[:arrow], "pass", self.code))
            want = int(rest[arrow + 1])
            return None if self.mqtt.connack == want else "CONNACK %d, not %d" % (self.mqtt.connack, want)
        if verb == "SUB":
            return None if self.mqtt.subscribe(rest[0]) else "SUBACK refused %s" % rest[0]
        if verb == "PUB":
            self.mqtt.publish(rest[0], rest[1])
            return None
        if verb == "RECV":
            secs = 30.0
            if rest and rest[0].replace(".", "").isdigit():
                secs, rest = float(rest[0]), rest[1:]
            end, last = time.monotonic() + secs, ""
            while time.monotonic() < end:
                payload = self.mqtt.message(end - time.monotonic())
                if payload is None:
                    break
                last = payload.decode("utf-8", "replace")
                try:
                    body = json.loads(payload)
                except ValueError:
                    continue
                if all(replay.check(body, c) is None for c in rest):
                    return None
            return "no message passed in %.0f s (last: %s)" % (secs, last[:300])
        return "unknown MQTT verb " + verb

    def ftp_line(self, verb, rest):
        arrow = rest.index("->") if "->" in rest else len(rest)
        want = int(rest[arrow + 1]) if arrow < len(rest) else None
        extra = rest[arrow + 2:]
        got = None
        if verb == "LOGIN":
            self.ftp = Ftps(context=tls())
            self.ftp.connect(self.host, self.fport)
            got = code_of(lambda: self.ftp.login("bblp", self.opt(rest[:arrow], "pass", self.code)))
        elif verb == "PROT_P":
            got = code_of(self.ftp.prot_p)
        elif verb == "CMD":
            got = code_of(lambda: self.ftp.sendcmd(rest[0]))
        elif verb == "STOR":
            data = replay.GCODE * (int(rest[1]) // len(replay.GCODE) + 1)
            got = code_of(lambda: self.ftp.storbinary("STOR " + rest[0], io.BytesIO(data[:int(rest[1])])))
        elif verb == "LIST":
            lines = []
            arg = rest[0] if arrow > 0 else ""
            got = code_of(lambda: self.ftp.retrlines(("LIST " + arg).strip(), lines.append))
            for e in extra:
                if e.startswith("has=") and not any(l.endswith(" " + e[4:]) for l in lines):
                    return "LIST has no %s: %s" % (e[4:], lines)
        elif verb == "QUIT":
            self.ftp.quit()
            return None
        else:
            return "unknown FTP verb " + verb
        return None if got == want else "reply %s, not %s" % (got, want)


def main():
    host, mport, fport, serial, code, path = sys.argv[1:7]
    s = Session(host, int(mport), int(fport), serial, code)
    n = 0
    for no, line in enumerate(open(path), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        toks = shlex.split(line.replace("{SERIAL}", serial))
        try:
            why = (s.mqtt_line if toks[0] == "MQTT" else s.ftp_line)(toks[1], toks[2:])
        except (OSError, EOFError, ValueError, IndexError) as e:
            why = "%s: %s" % (type(e).__name__, e)
        n += 1
        if why:
            print("%s:%d: %s\n  line: %s" % (path, no, why, line.strip()))
            return 1
    print("%s: %d lines as the client expects" % (path, n))
    return 0


if __name__ == "__main__":
    sys.exit(main())
