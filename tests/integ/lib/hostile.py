#!/usr/bin/python3
"""tests/integ/lib/hostile.py - heavy and hostile HTTP clients of issue 30,
over raw loopback sockets so every byte is the test's: keyless keep-alive
clients, event streams, slow heads and requests framed two ways.  Used by
tests/integ/farmd_conns.sh (cases 2, 3 and 5) and
tests/bench/bench_api_conns.sh.

Clients bind to 127.0.0.N (every 127/8 address is loopback on Linux), so
"from 8 addresses" is real.  Nothing here sleeps to assert: each wait is
for a condition, with a deadline.
"""
import socket, time

HOST = "127.0.0.1"


def connect(port, src="127.0.0.1", timeout=20):
    s = socket.socket()
    s.settimeout(timeout)
    s.bind((src, 0))
    s.connect((HOST, port))
    return s


def read_head(s):
    """(status, headers with lower-case names, bytes after the head);
    status 0 when the server closed first."""
    data = b""
    while b"\r\n\r\n" not in data:
        try:
            chunk = s.recv(65536)
        except OSError:
            chunk = b""
        if not chunk:
            return 0, {}, data
        data += chunk
    head, rest = data.split(b"\r\n\r\n", 1)
    lines = head.decode("latin-1").split("\r\n")
    hdrs = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        hdrs[k.strip().lower()] = v.strip()
    return int(lines[0].split()[1]), hdrs, rest


def read_response(s):
    """(status, headers, body) of one response framed by Content-Length or
    chunked; status 0 when the server closed first."""
    st, hdrs, rest = read_head(s)
    if not st:
        return 0, {}, b""
    if "content-length" in hdrs:
        n = int(hdrs["content-length"])
        while len(rest) < n:
            chunk = s.recv(65536)
            if not chunk:
                break
            rest += chunk
        return st, hdrs, rest[:n]
    if hdrs.get("transfer-encoding", "").lower() == "chunked":
        while not rest.endswith(b"0\r\n\r\n"):
            chunk = s.recv(65536)
            if not chunk:
                break
            rest += chunk
    return st, hdrs, rest


def get(port, path, key=None, src="127.0.0.1", timeout=20, keep=False):
    s = connect(port, src, timeout)
    extra = "X-Api-Key: %s\r\n" % key if key else ""
    conn = "" if keep else "Connection: close\r\n"
    s.sendall(("GET %s HTTP/1.1\r\nHost: x\r\n%s%s\r\n" % (path, extra, conn)).encode())
    st, hdrs, body = read_response(s)
    if keep:
        return s, st
    s.close()
    return st, body


def keyed_ok(port, key, src="127.0.0.1", timeout=20):
    """A keyed GET /api/printers answered 200 (on a new connection)."""
    try:
        st, _ = get(port, "/api/printers", key, src, timeout)
        return st == 200
    except OSError:
        return False


def _many(n, open_one):
    """n connections made by open_one(i) -> (socket, status); returns
    (sockets kept open, {status: count})."""
    socks, seen = [], {}
    for i in range(n):
        try:
            s, st = open_one(i)
        except OSError:
            s, st = None, 0
        seen[st] = seen.get(st, 0) + 1
        if s:
            socks.append(s)
    return socks, seen


def keyless_keepalive(port, n, n_addr=8, path="/favicon.svg"):
    """n keep-alive connections without a key from 127.0.0.2.., each having
    fetched path once."""
    return _many(n, lambda i: get(port, path, None, "127.0.0.%d" % (2 + i % n_addr), 20,
                                  keep=True))


def streams(port, key, n, srcs):
    """n GET /api/events on key from the addresses srcs in turn."""
    def one(i):
        s = connect(port, srcs[i % len(srcs)])
        s.sendall(("GET /api/events HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n\r\n"
                   % key).encode())
        return s, read_head(s)[0]
    return _many(n, one)


def parse_responses(data):
    """The statuses of the responses in data, one after another."""
    out = []
    while b"\r\n\r\n" in data:
        head, data = data.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        hdrs = {k.strip().lower(): v.strip()
                for k, _, v in (line.partition(":") for line in lines[1:])}
        out.append(int(lines[0].split()[1]))
        if "content-length" in hdrs:
            data = data[int(hdrs["content-length"]):]
        elif hdrs.get("transfer-encoding", "").lower() == "chunked":
            end = data.find(b"\r\n0\r\n\r\n")
            data = data[end + 7:] if end >= 0 else b""
    return out


def raw_responses(port, raw, timeout=10):
    """Send raw bytes on one connection; the statuses of every response
    until the server closes it (or timeout passes: then 'open' is last)."""
    s = connect(port, timeout=timeout)
    s.sendall(raw)
    data, still_open = b"", False
    try:
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    except socket.timeout:
        still_open = True
    except OSError:
        pass
    s.close()
    return parse_responses(data) + (["open"] if still_open else [])


def close_all(socks):
    for s in socks:
        try:
            s.close()
        except OSError:
            pass
