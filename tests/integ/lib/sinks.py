#!/usr/bin/python3
# tests/integ/lib/sinks.py - loopback receivers for the daemon's
# notifications (farmd_notify.sh), real servers on ports the kernel picks:
#   sinks.py http DIR  a webhook listener: every request is appended to
#                      DIR/http.log as one JSON line (path, headers, body,
#                      the status answered); the first request gets a 500,
#                      the rest 200, so the daemon's retry is seen.
#   sinks.py smtp DIR  an SMTP sink (aiosmtpd, Debian python3-aiosmtpd):
#                      every mail is appended to DIR/smtp.log as one JSON
#                      line (envelope sender, recipients, the message).
# Each writes its port to DIR/KIND.port once listening.
import asyncio, json, os, sys
from http.server import BaseHTTPRequestHandler, HTTPServer

kind, out = sys.argv[1], sys.argv[2]


def record(line):
    with open(os.path.join(out, kind + ".log"), "a") as f:
        f.write(json.dumps(line) + "\n")


def ready(port):
    tmp = os.path.join(out, kind + ".port.tmp")
    with open(tmp, "w") as f:
        f.write(str(port))
    os.rename(tmp, os.path.join(out, kind + ".port"))


class Hook(BaseHTTPRequestHandler):
    n = 0

    def do_POST(self):
        body = self.rfile.read(int(self.headers.get("Content-Length", "0"))).decode()
        status = 500 if Hook.n == 0 else 200
        Hook.n += 1
        record({"path": self.path, "headers": dict(self.headers), "body": body, "status": status})
        self.send_response(status)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args):
        pass


class Mail:
    async def handle_DATA(self, server, session, envelope):
        record({"from": envelope.mail_from, "to": envelope.rcpt_tos,
                "data": envelope.content.decode("utf-8", "replace")})
        return "250 OK"


if kind == "http":
    srv = HTTPServer(("127.0.0.1", 0), Hook)
    ready(srv.server_address[1])
    srv.serve_forever()
else:
    from aiosmtpd.smtp import SMTP
    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    srv = loop.run_until_complete(loop.create_server(lambda: SMTP(Mail()), "127.0.0.1", 0))
    ready(srv.sockets[0].getsockname()[1])
    loop.run_forever()
