#!/usr/bin/python3
"""tests/integ/lib/slicers.py - the requests slicers send to an OctoPrint or
Moonraker host, replayed byte for byte over a socket, and a strict parser
of the Prometheus text format (0.0.4).  Used by farmd_upload.sh.

The requests are written from the clients' sources:
  PrusaSlicer 2.9 and OrcaSlicer src/slic3r/Utils/OctoPrint.cpp (libcurl:
    Host, User-Agent, Accept, then X-Api-Key; test = GET api/version; upload =
    curl mime parts print, path, file in that order, boundary of 24 dashes
    and 16 hex digits, the file part typed application/octet-stream);
  Cura OctoPrintPlugin OctoPrintOutputDevice.py (Qt: X-Api-Key and
    User-Agent set first, QHttpMultiPart boundary "boundary_.oOo._" + base64,
    quoted in Content-Type, each part Content-Disposition then Content-Type;
    parts path, file[, select[, print]]; then, when it does not print at once,
    POST {"command": "select"} to the Location after "api/").
Each function returns (status, headers dict (lower-case names), body bytes).
"""
import base64, json, os, re, socket, sys

HOST = "127.0.0.1"


def request(port, raw, timeout=60, body=None):
    """Send raw; with body, first wait for 100 Continue as curl does when it
    sends Expect: 100-continue (a final answer instead ends the request)."""
    s = socket.create_connection((HOST, port), timeout=timeout)
    s.sendall(raw)
    data = b""
    if body is not None:
        while b"\r\n\r\n" not in data:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
        if data.startswith(b"HTTP/1.1 100"):
            data = data.partition(b"\r\n\r\n")[2]
            s.sendall(body)
    while True:
        chunk = s.recv(65536)
        if not chunk:
            break
        data += chunk
        head, sep, body = data.partition(b"\r\n\r\n")
        if sep:
            m = re.search(rb"(?im)^content-length: *(\d+)", head)
            if (m and len(body) >= int(m.group(1))) or re.match(rb"HTTP/1\.[01] (204|304)", head):
                break
    s.close()
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for l in lines[1:]:
        k, _, v = l.partition(":")
        headers[k.strip().lower()] = v.strip()
    return status, headers, body


def curl_get(port, path, ua, key):
    return request(port, ("GET %s HTTP/1.1\r\nHost: %s:%d\r\nUser-Agent: %s\r\nAccept: */*\r\n"
                          "X-Api-Key: %s\r\n\r\n" % (path, HOST, port, ua, key)).encode())


def curl_mime(port, path, ua, key, fields, filename, data):
    """libcurl's multipart POST as PrusaSlicer/Orca's Http class builds it."""
    boundary = "------------------------" + os.urandom(8).hex()
    body = b""
    for name, value in fields:
        body += ("--%s\r\nContent-Disposition: form-data; name=\"%s\"\r\n\r\n%s\r\n"
                 % (boundary, name, value)).encode()
    if filename is not None:
        body += ("--%s\r\nContent-Disposition: form-data; name=\"file\"; filename=\"%s\"\r\n"
                 "Content-Type: application/octet-stream\r\n\r\n" % (boundary, filename)).encode()
        body += data + b"\r\n"
    body += ("--%s--\r\n" % boundary).encode()
    # curl asks for 100-continue before a body over 1 MiB (libcurl 8)
    expect = "Expect: 100-continue\r\n" if len(body) > (1 << 20) else ""
    head = ("POST %s HTTP/1.1\r\nHost: %s:%d\r\nUser-Agent: %s\r\nAccept: */*\r\n"
            "X-Api-Key: %s\r\nContent-Length: %d\r\n"
            "Content-Type: multipart/form-data; boundary=%s\r\n%s\r\n"
            % (path, HOST, port, ua, key, len(body), boundary, expect)).encode()
    if expect:
        return request(port, head, body=body)
    return request(port, head + body)


def prusaslicer(port, key, filename, data, print_=True, ua="PrusaSlicer/2.9.4"):
    """PrusaSlicer's OctoPrint host: test (GET api/version), then the upload."""
    st, h, b = curl_get(port, "/api/version", ua, key)
    if st != 200:
        return st, h, b
    v = json.loads(b)
    assert "api" in v and v["text"].startswith("OctoPrint"), v
    return curl_mime(port, "/api/files/local", ua, key,
                     [("print", "true" if print_ else "false"), ("path", "")], filename, data)


def orcaslicer(port, key, filename, data, print_=True):
    return prusaslicer(port, key, filename, data, print_, ua="OrcaSlicer/2.3.0")


CURA_UA = "Cura/5.8.1 OctoPrintPlugin/3.7.3"


def qt_head(method, path, port, key, ctype, length):
    h = "%s %s HTTP/1.1\r\nHost: %s:%d\r\nX-Api-Key: %s\r\nUser-Agent: %s\r\n" % (
        method, path, HOST, port, key, CURA_UA)
    if ctype:
        h += "Content-Type: %s\r\n" % ctype
    if length is not None:
        h += "Content-Length: %d\r\n" % length
    return h + "Connection: Keep-Alive\r\nAccept-Encoding: gzip, deflate\r\nAccept-Language: en-US,*\r\n\r\n"


def cura_get(port, key, path):
    return request(port, qt_head("GET", path, port, key, "application/json", None).encode())


def cura(port, key, filename, data, auto_print=True, auto_select=True):
    """Cura's plugin: connection test, upload, then select through the Location."""
    for p in ("/api/settings", "/api/version", "/api/printerprofiles", "/api/printer", "/api/job"):
        st, h, b = cura_get(port, key, p)
        if st != 200:
            return st, h, b, None
    settings = json.loads(cura_get(port, key, "/api/settings")[2])
    wait_for_analysis = settings.get("gcodeAnalysis", {}).get("runAt") == "idle"
    boundary = "boundary_.oOo._" + base64.b64encode(os.urandom(24)).decode()
    parts = [('form-data; name="path"', b"", "text/plain"),
             ('form-data; name="file"; filename="%s"' % filename, data, "application/octet-stream")]
    in_upload = not wait_for_analysis
    if in_upload and (auto_select or auto_print):
        parts.append(('form-data; name="select"', b"true", "text/plain"))
    if in_upload and auto_print:
        parts.append(('form-data; name="print"', b"true", "text/plain"))
    body = b""
    for disp, d, ct in parts:
        body += ("--%s\r\nContent-Disposition: %s\r\nContent-Type: %s\r\n\r\n" % (boundary, disp, ct)).encode()
        body += d + b"\r\n"
    body += ("--%s--\r\n" % boundary).encode()
    head = qt_head("POST", "/api/files/local", port, key,
                   'multipart/form-data; boundary="%s"' % boundary, len(body))
    st, h, b = request(port, head.encode() + body)
    if st != 201:
        return st, h, b, None
    loc = h["location"]  # the plugin fails without it
    end_point = loc.split("api/", 1)[1]
    sel = None
    if not auto_print and (auto_print or auto_select):
        cmd = json.dumps({"command": "select"}).encode()
        sel = request(port, qt_head("POST", "/api/" + end_point, port, key, "application/json",
                                    len(cmd)).encode() + cmd)
    return st, h, b, sel


def moonraker(port, key, filename, data, print_=True):
    """A Moonraker client's connection test and upload (Moonraker docs'
    fields root, path, print; Orca also lists roots)."""
    ua = "OrcaSlicer/2.3.0"
    for p in ("/server/info", "/server/files/roots"):
        st, h, b = curl_get(port, p, ua, key)
        if st != 200:
            return st, h, b
    return curl_mime(port, "/server/files/upload", ua, key,
                     [("root", "gcodes"), ("path", ""), ("print", "true" if print_ else "false")],
                     filename, data)


# ---- Prometheus text format 0.0.4, strictly ----

NAME = r"[a-zA-Z_:][a-zA-Z0-9_:]*"
LNAME = r"[a-zA-Z_][a-zA-Z0-9_]*"
VALUE = r"(?:[+-]?(?:\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)|[+-]?Inf|NaN)"


def parse_labels(s, where):
    """The inside of {...}: name="value" pairs, escapes \\\\ \\" \\n only."""
    out, i = {}, 0
    while i < len(s):
        m = re.match(LNAME, s[i:])
        assert m, "%s: bad label name at %r" % (where, s[i:])
        name = m.group(0)
        i += len(name)
        assert s[i:i + 2] == '="', "%s: label %s: expected =\"" % (where, name)
        i += 2
        v = ""
        while True:
            assert i < len(s), "%s: unterminated label value" % where
            c = s[i]
            if c == "\\":
                nxt = s[i + 1:i + 2]
                assert nxt in ("\\", '"', "n"), "%s: bad escape \\%s" % (where, nxt)
                v += {"\\": "\\", '"': '"', "n": "\n"}[nxt]
                i += 2
            elif c == '"':
                i += 1
                break
            else:
                assert c != "\n", where
                v += c
                i += 1
        assert name not in out, "%s: label %s twice" % (where, name)
        out[name] = v
        if i < len(s):
            assert s[i] == ",", "%s: expected , after label %s" % (where, name)
            i += 1
            # a trailing comma is allowed before }
    return out


def parse_prom(text):
    """{(name, frozenset(labels.items())): value} plus types; asserts the rules:
    HELP/TYPE at most once per family and TYPE before its samples; samples of
    a family together; histograms with _bucket (le, cumulative, ending +Inf),
    _sum and _count equal to the +Inf bucket; counters >= 0; no duplicates."""
    assert text.endswith("\n"), "text must end with a newline"
    types, helps, samples, seen_families, order = {}, {}, {}, [], []
    current = None
    for n, line in enumerate(text.split("\n")[:-1], 1):
        where = "line %d" % n
        if line.startswith("#"):
            m = re.match(r"# (HELP|TYPE) (%s) (.*)$" % NAME, line)
            if not m:
                assert not line.startswith("# HELP") and not line.startswith("# TYPE"), where
                continue
            kind, fam, rest = m.groups()
            if kind == "TYPE":
                assert rest in ("counter", "gauge", "histogram", "summary", "untyped"), where
                assert fam not in types, "%s: second TYPE for %s" % (where, fam)
                assert fam not in seen_families, "%s: TYPE of %s after its samples" % (where, fam)
                types[fam] = rest
            else:
                assert fam not in helps, "%s: second HELP for %s" % (where, fam)
                assert "\n" not in rest
                helps[fam] = rest
            continue
        assert line.strip(), "%s: blank line" % where
        m = re.match(r"(%s)(\{(.*)\})? (%s)( -?\d+)?$" % (NAME, VALUE), line)
        assert m, "%s: not a sample: %r" % (where, line)
        name, _, lbl, value = m.group(1), m.group(2), m.group(3), m.group(4)
        labels = parse_labels(lbl or "", where)
        fam = name
        for suf in ("_bucket", "_sum", "_count"):
            base = name[:-len(suf)]
            if name.endswith(suf) and types.get(base) in ("histogram", "summary"):
                fam = base
        if fam != current:
            assert fam not in seen_families, "%s: samples of %s not together" % (where, fam)
            seen_families.append(fam)
            current = fam
        key = (name, frozenset(labels.items()))
        assert key not in samples, "%s: duplicate sample %r" % (where, key)
        v = float(value.replace("Inf", "inf"))
        samples[key] = v
        if types.get(fam) == "counter":
            assert v >= 0, where
    for fam, t in types.items():
        if t != "histogram":
            continue
        series = {}
        for (name, lbls), v in samples.items():
            if name == fam + "_bucket":
                d = dict(lbls)
                assert "le" in d, "%s bucket without le" % fam
                le = d.pop("le")
                series.setdefault(frozenset(d.items()), []).append(
                    (float(le.replace("Inf", "inf")), v))
        assert series, "histogram %s has no buckets" % fam
        for lbls, buckets in series.items():
            buckets.sort()
            assert buckets[-1][0] == float("inf"), "%s %s: no le=\"+Inf\"" % (fam, dict(lbls))
            for a, b in zip(buckets, buckets[1:]):
                assert a[1] <= b[1], "%s %s: buckets not cumulative" % (fam, dict(lbls))
            count = samples.get((fam + "_count", lbls))
            assert count is not None and (fam + "_sum", lbls) in samples, "%s: no _sum/_count" % fam
            assert count == buckets[-1][1], "%s: _count != +Inf bucket" % fam
    return samples, types


def metric(samples, name, **labels):
    return samples.get((name, frozenset(labels.items())))


if __name__ == "__main__":
    # self-test of the parser: it must refuse what the format forbids
    good = ('# HELP a_total A.\n# TYPE a_total counter\na_total{x="q\\"\\\\\\n"} 1\n'
            '# TYPE h histogram\nh_bucket{le="1"} 1\nh_bucket{le="+Inf"} 2\nh_sum 3\nh_count 2\n')
    parse_prom(good)
    bad = [good.replace('le="+Inf"', 'le="2"'), good.replace("h_count 2", "h_count 3"),
           good + "a_total 2\n", good.replace('\\"', '"'), good[:-1],
           good.replace("# TYPE a_total counter\n", "") + "# TYPE a_total counter\n",
           good.replace('h_bucket{le="1"} 1', 'h_bucket{le="1"} 3')]
    for b in bad:
        try:
            parse_prom(b)
        except AssertionError:
            continue
        sys.exit("parser accepted bad text:\n" + b)
    print("parser self-test ok")
