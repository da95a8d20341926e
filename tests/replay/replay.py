#!/usr/bin/python3
"""tests/replay/replay.py - replay one recorded client session against a
simulated printer and check every answer's status and shape.

usage: replay.py URL KEY SESSION_FILE

A session file (tests/replay/clients/KIND-CLIENT.txt) names, in comments,
the client and version it follows; each other line is one request:

  [UNTIL SECONDS] METHOD PATH [hdr:NAME=VALUE]... [BODY] -> STATUS [CHECK]...

BODY is json=TEXT (sent as application/json), form=F,F,... (multipart;
F is name=value, or name=@FILE for a small G-code file called FILE) or
raw=FILE (that G-code as the raw body, PrusaLink's PUT).  Every request
carries X-Api-Key: KEY.  STATUS is the status expected.  A CHECK is a path
into the JSON answer: a.b (present), a[] (a list), a[].b (every element of
the list has b), a[0].b (its first element), followed by nothing (must be
present), =VALUE (equal: JSON, else the text; quotes go as in a shell), ~REGEX (a string matching), :TYPE (str num int
bool null list obj) or >NAME (keep the value: {NAME} in a later path or
body stands for it); !PATH: absent.  UNTIL repeats the request every 20 ms
until the status and checks hold or SECONDS pass (a client waiting for a
state).  Lines are quoted as a shell would (shlex).  The first failing line
ends the run with its file and line number; exit status 1.

Push sockets (tests/replay/wsclient.py) take lines beginning with WS:

  WS OPEN PATH [hdr:NAME=VALUE]... [sockjs] -> STATUS   open the socket (101), or
                                             expect the handshake to be refused
  WS SEND TEXT              send one text message ({NAME} substituted)
  WS NEXT [SECONDS] CHECK...  the very next message (JSON) must pass the checks
  WS RECV [SECONDS] CHECK...  skip messages until one passes them
  WS ONLY [SECONDS] SKIP -- CHECK...  skip messages that pass the check SKIP;
                            the first other one must pass the CHECKs
  WS FRAME HEX              send these bytes as they are (a broken frame)
  WS CLOSED [SECONDS] [code=N]  the server closes the socket (with close code N)
  WS CLOSE                  close it

A line RUN TEXT runs TEXT in the shell (the test's environment; a reload
of the daemon, say) and fails when it exits other than 0.

SECONDS defaults to 30.  sockjs speaks SockJS's websocket transport ("o",
'a["..."]' frames).
"""
import json, re, shlex, socket, subprocess, sys, time, urllib.error, urllib.request, uuid

import wsclient

GCODE = b"; replayed by tests/replay/replay.py\nG28\nG1 X10 Y10 F3000\n" + \
    b"".join(b"G1 X%d Y%d\n" % (10 + i % 50, 10 + i % 40) for i in range(400)) + b"M400\n"
MISSING = object()
VARS = {}  # values kept by >NAME checks


def walk(v, path):
    """The values at path ("a.b", "a[].b", "a[0]"), MISSING where one is absent."""
    vals = [v]
    for part in re.findall(r"[^.\[\]]+|\[\d*\]", path):
        nxt = []
        for x in vals:
            if x is MISSING:
                nxt.append(MISSING)
            elif part == "[]":
                if not isinstance(x, list):
                    nxt.append(MISSING)
                else:
                    nxt.extend(x)
            elif part.startswith("["):
                i = int(part[1:-1])
                nxt.append(x[i] if isinstance(x, list) and i < len(x) else MISSING)
            else:
                nxt.append(x.get(part, MISSING) if isinstance(x, dict) else MISSING)
        vals = nxt
    return vals


TYPES = {"str": lambda x: isinstance(x, str), "num": lambda x: isinstance(x, (int, float))
         and not isinstance(x, bool), "int": lambda x: isinstance(x, int) and not isinstance(x, bool),
         "bool": lambda x: isinstance(x, bool), "null": lambda x: x is None,
         "list": lambda x: isinstance(x, list), "obj": lambda x: isinstance(x, dict)}


def literal(arg):
    """A check's value: JSON (true, 3, 100.0, null), else the text itself."""
    try:
        return json.loads(arg)
    except ValueError:
        return arg


def check(body, chk):
    """None if chk holds on body, else why not."""
    if chk.startswith("!"):
        vals = walk(body, chk[1:])
        return None if all(v is MISSING for v in vals) else "%s is present" % chk[1:]
    m = re.match(r"^([^=~:>]+)(?:([=~:>])(.*))?$", chk)
    path, op, arg = m.group(1), m.group(2), m.group(3)
    if path.endswith("[]") and op is None:
        return None if all(isinstance(v, list) for v in walk(body, path[:-2])) else \
            "%s is not a list" % path[:-2]
    vals = walk(body, path)  # empty: an empty list on the way, which holds vacuously
    for v in vals:
        if v is MISSING:
            return "%s is absent" % path
        if op == ">":
            VARS[arg] = v
        if op == "=" and v != literal(arg):
            return "%s is %s, not %s" % (path, json.dumps(v), arg)
        if op == "~" and not (isinstance(v, str) and re.search(arg, v)):
            return "%s is %s, not matching /%s/" % (path, json.dumps(v), arg)
        if op == ":" and not TYPES[arg](v):
            return "%s is %s, not of type %s" % (path, json.dumps(v), arg)
    return None


def build(method, url, key, opts):
    headers = {"X-Api-Key": key, "User-Agent": "slimfarm-replay"}
    data = None
    for o in opts:
        k, _, v = o.partition("=")
        if k.startswith("hdr:"):
            headers[k[4:]] = v
        elif k == "json":
            data = v.encode()
            headers["Content-Type"] = "application/json"
        elif k == "raw":
            data = GCODE
            headers["Content-Type"] = "text/x.gcode"
        elif k == "form":
            b = "----replay" + uuid.uuid4().hex
            parts = []
            for f in v.split(","):
                n, _, val = f.partition("=")
                if val.startswith("@"):
                    parts.append(('--%s\r\nContent-Disposition: form-data; name="%s"; filename="%s"\r\n'
                                  'Content-Type: application/octet-stream\r\n\r\n' % (b, n, val[1:])).encode()
                                 + GCODE + b"\r\n")
                else:
                    parts.append(('--%s\r\nContent-Disposition: form-data; name="%s"\r\n\r\n%s\r\n'
                                  % (b, n, val)).encode())
            data = b"".join(parts) + ("--%s--\r\n" % b).encode()
            headers["Content-Type"] = "multipart/form-data; boundary=" + b
        else:
            raise ValueError("unknown option " + o)
    return urllib.request.Request(url, data=data, headers=headers, method=method)


def send(req):
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


WS = {}  # the open push socket


def ws_line(base, key, toks):
    """One WS line: (why it failed or None, the last message's text)."""
    verb, rest = toks[1], toks[2:]
    if verb == "OPEN":
        arrow = rest.index("->")
        path, opts, want = rest[0], rest[1:arrow], int(rest[arrow + 1])
        hdrs = {o[4:].partition("=")[0]: o[4:].partition("=")[2] for o in opts if o.startswith("hdr:")}
        try:
            WS["ws"] = wsclient.Ws(base, path, hdrs, sockjs="sockjs" in opts)
            status = 101
        except wsclient.WsError as e:
            m = re.search(r"HTTP/1.1 (\d+)", str(e))
            if not m:
                return str(e), ""
            status = int(m.group(1))
        return (None if status == want else "handshake %d, not %d" % (status, want)), ""
    ws = WS.get("ws")
    if ws is None:
        return "no socket open", ""
    if verb == "SEND":
        ws.send(rest[0])
        return None, ""
    if verb == "FRAME":
        ws.sock.sendall(bytes.fromhex(rest[0]))
        return None, ""
    if verb == "CLOSE":
        ws.close()
        WS.pop("ws")
        return None, ""
    secs = 30.0
    if rest and re.match(r"^\d+(\.\d+)?$", rest[0]):
        secs, rest = float(rest[0]), rest[1:]
    skip = None
    if verb == "ONLY":
        skip, rest = rest[0], rest[rest.index("--") + 1:]
    end = time.monotonic() + secs
    last, why = "", "nothing arrived"
    while True:
        try:
            text = ws.recv(max(0.0, end - time.monotonic()))
        except socket.timeout:
            return "%s in %.0f s (last: %s)" % (why, secs, last[:300]), last
        if text is None:
            code = [c for c in rest if c.startswith("code=")]
            if verb != "CLOSED":
                return "the server closed the socket", last
            if code and str(getattr(ws, "close_code", None)) != code[0][5:]:
                return "closed with code %s, not %s" % (getattr(ws, "close_code", None), code[0][5:]), last
            return None, last
        if verb == "CLOSED":
            why, last = "still open", text
            continue
        last = text
        try:
            body = json.loads(text)
        except ValueError:
            return "message is not JSON: %r" % text[:200], text
        if skip and check(body, skip) is None:
            continue
        why = None
        for c in rest:
            why = why or check(body, c)
        if why is None or verb in ("NEXT", "ONLY"):
            return why, text


def run_line(base, key, toks):
    if toks[0] == "RUN":
        rc = subprocess.call(toks[1], shell=True)
        return (None if rc == 0 else "exit status %d" % rc), b""
    if toks[0] == "WS":
        why, text = ws_line(base, key, toks)
        return why, text.encode()
    until = 0
    if toks[0] == "UNTIL":
        until, toks = float(toks[1]), toks[2:]
    arrow = toks.index("->")
    method, path, opts = toks[0], toks[1], toks[2:arrow]
    want, checks = int(toks[arrow + 1]), toks[arrow + 2:]
    end = time.monotonic() + until
    while True:
        status, raw = send(build(method, base + path, key, opts))
        why = None if status == want else "status %d, not %d" % (status, want)
        if why is None and checks:
            try:
                body = json.loads(raw)
            except ValueError:
                body, why = None, "the answer is not JSON: %r" % raw[:200]
            for c in checks:
                why = why or check(body, c)
        if why is None or time.monotonic() >= end:
            return why, raw
        time.sleep(0.02)


def main():
    base, key, session = sys.argv[1].rstrip("/"), sys.argv[2], sys.argv[3]
    n = 0
    for no, line in enumerate(open(session), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        for k, v in VARS.items():
            line = line.replace("{%s}" % k, str(v))
        why, raw = run_line(base, key, shlex.split(line))
        n += 1
        if why:
            print("%s:%d: %s\n  request: %s\n  answer: %s" % (session, no, why, line.strip(),
                                                             raw[:400].decode("utf-8", "replace")))
            return 1
    print("%s: %d requests as the client expects" % (session, n))
    return 0


if __name__ == "__main__":
    sys.exit(main())
