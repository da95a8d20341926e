/*
 * test_farmcfg.c - the farm config parser: defaults, every option kind,
 * strict errors naming file:line, option and section, and config/farm.ini
 * kept in step with the parser (uncommented, it must parse, and it must
 * document every option).
 */
#include "../../drivers/drv_link.h"
#include "../../drivers/gpolicy.h"
#include "../../src/base/buf.h"
#include "../../src/farm/farmcfg.h"
#include "../t.h"

/* Printer p's driver config, as the farm makes it (text points into p). */
static struct drv_config
link_of(const struct farmcfg_printer *p)
{
    struct drv_config dc = { .name = p->name, .kind = p->driver };
    drv_link_config(&p->link, drv_kind_find(p->driver), &dc);
    return dc;
}

/* The line option name was given on in p's section, 0 if it was not. */
static int
line_of(const struct farmcfg_printer *p, const char *name)
{
    const struct drv_link_val *v = drv_link_get(&p->link, drv_link_option(name));
    return v ? v->line : 0;
}

static int
parse(struct farmcfg *c, const char *text, struct sf_err *err)
{
    farmcfg_init(c);
    return farmcfg_parse(c, text, strlen(text), "farm.ini", err);
}

T_CASE(farmcfg_full_example)
{
    struct farmcfg c;
    struct sf_err err;
    const char *text = "# a farm\n"
                       "[farm]\n"
                       "listen: 0.0.0.0:8080\n"
                       "data_dir = /srv/farm   # inline comment\n"
                       "api_keys: aaaaaaaaaaaaaaaa, bbbbbbbbbbbbbbbb\n"
                       "api_keys_readonly: rrrrrrrrrrrrrrrr\n"
                       "upload_max_mb: 8\n"
                       "\n"
                       "[printer mk3-a]\n"
                       "  driver: marlin\n"
                       "  port: pty:/dev/pts/7\n"
                       "  material: PETG ; inline\n"
                       "  nozzle_mm: 0.6\n"
                       "  bed_size: 250, 210, 200\n"
                       "  auto_eject: yes\n"
                       "  group: big\n"
                       "  buffer_lines: 8\n"
                       "  rx_buffer: 256\n"
                       "[printer voron]\r\n"
                       "driver: marlin\r\n"
                       "port: tcp://10.0.0.5:7125\r\n"
                       "enabled: false\r\n";
    T_OK(parse(&c, text, &err), &err);
    T_EQ_STR(c.listen_host, "0.0.0.0");
    T_EQ_INT(c.listen_port, 8080);
    T_EQ_STR(c.data_dir, "/srv/farm");
    T_EQ_INT(c.upload_max_bytes, 8 << 20);
    T_EQ_INT(c.n_keys, 3);
    T_TRUE(farmcfg_key(&c, "bbbbbbbbbbbbbbbb") && !farmcfg_key(&c, "bbbbbbbbbbbbbbbb")->read_only);
    T_TRUE(farmcfg_key(&c, "rrrrrrrrrrrrrrrr")->read_only);
    T_TRUE(farmcfg_key(&c, "rrrrrrrrrrrrrrr") == NULL);
    T_TRUE(farmcfg_key(&c, "rrrrrrrrrrrrrrrrr") == NULL);
    T_TRUE(farmcfg_key(&c, "") == NULL);
    T_EQ_INT(c.n_printers, 2);
    const struct farmcfg_printer *p = farmcfg_printer(&c, "mk3-a");
    T_TRUE(p != NULL);
    T_EQ_STR(p->driver, "marlin");
    T_EQ_STR(link_of(p).port, "pty:/dev/pts/7");
    T_EQ_STR(p->material, "PETG");
    T_EQ_DBL(p->nozzle_mm, 0.6, 0);
    T_EQ_DBL(p->bed_mm[0], 250, 0);
    T_EQ_DBL(p->bed_mm[2], 200, 0);
    T_TRUE(p->auto_eject && p->enabled);
    T_EQ_INT(link_of(p).baud, 115200);
    T_EQ_DBL(p->overhang_deg, 45, 0);
    T_EQ_STR(p->group, "big");
    T_EQ_INT(link_of(p).buffer_lines, 8);
    T_EQ_INT(link_of(p).rx_buffer, 256);
    p = farmcfg_printer(&c, "voron");
    T_EQ_STR(link_of(p).port, "tcp://10.0.0.5:7125");
    T_TRUE(!p->enabled);
    T_EQ_STR(p->material, "PLA");
    T_EQ_INT(link_of(p).buffer_lines, 4);
    T_EQ_INT(link_of(p).rx_buffer, 128);
    T_EQ_INT(p->line, 19);
    farmcfg_release(&c);
    T_EQ_INT(c.n_printers, 0);
}

T_CASE(farmcfg_gcode_policy_options)
{
    struct farmcfg c;
    struct sf_err err;
    T_OK(parse(&c,
               "[printer a]\ndriver: marlin\nport: x\nattended: true\nallow_gcode: m500, M997\n"
               "[printer b]\ndriver: marlin\nport: y\n",
               &err),
         &err);
    struct gpolicy p;
    struct gpolicy_verdict v;
    farmcfg_policy(&c.printers[0], &p);
    T_TRUE(p.attended);
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_FILE, "M997", 4, &v), GPOLICY_PASS);
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_FILE, "M600", 4, &v), GPOLICY_PASS);
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_FILE, "M502", 4, &v), GPOLICY_REFUSE);
    farmcfg_policy(&c.printers[1], &p); /* the defaults: unattended, nothing allowed */
    T_TRUE(!p.attended);
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_FILE, "M600", 4, &v), GPOLICY_REFUSE);
    farmcfg_release(&c);
}

T_CASE(farmcfg_octoprint_printer)
{
    struct farmcfg c;
    struct sf_err err;
    const char *text = "[printer octo]\ndriver: octoprint\nurl: https://pi.local:5000/octo/\n"
                       "api_key: ABCDEF0123456789\npoll_ms: 2000\n"
                       "[printer octo2]\ndriver: octoprint\nurl: http://10.0.0.9\napi_key: k\n";
    T_OK(parse(&c, text, &err), &err);
    const struct farmcfg_printer *p = farmcfg_printer(&c, "octo");
    T_EQ_STR(link_of(p).url, "https://pi.local:5000/octo/");
    T_EQ_STR(link_of(p).api_key, "ABCDEF0123456789");
    T_EQ_INT(link_of(p).poll_ms, 2000);
    T_EQ_INT(line_of(p, "url"), 3);
    T_EQ_INT(link_of(farmcfg_printer(&c, "octo2")).poll_ms, 1000);
    farmcfg_release(&c);
}

/* Port 0: the kernel picks a free one (the integration tests run side by side). */
T_CASE(farmcfg_search_policy)
{
    struct farmcfg c;
    struct sf_err err;
    T_OK(parse(&c, "[farm]\ngram_seconds: 30\nmaterial_first: yes\n", &err), &err);
    T_EQ_DBL(c.gram_s, 30, 0);
    T_TRUE(c.material_first);
    farmcfg_release(&c);
}

T_CASE(farmcfg_listen_port_zero)
{
    struct farmcfg c;
    struct sf_err err;
    T_OK(parse(&c, "[farm]\nlisten: 127.0.0.1:0\n", &err), &err);
    T_EQ_STR(c.listen_host, "127.0.0.1");
    T_EQ_INT(c.listen_port, 0);
    /* the search's policy by default: a gram is worth a minute, never slower */
    T_EQ_DBL(c.gram_s, 60, 0);
    T_TRUE(!c.material_first);
    farmcfg_release(&c);
}

T_CASE(farmcfg_errors_name_file_line_option_section)
{
    struct farmcfg c;
    struct sf_err err;
    static const struct {
        const char *text, *msg;
    } bad[] = {
        { "[farm]\nlisten: 1.2.3.4:80\n[printer mk3]\ndriver: marlin\nbaud_rate: 9600\n",
          "farm.ini:5: option 'baud_rate' is not valid in section 'printer mk3'" },
        { "[farm]\nport: 3\n", "farm.ini:2: option 'port' is not valid in section 'farm'" },
        { "[farms]\n", "farm.ini:1: section 'farms' is not valid" },
        { "\n\n[printer]\n", "farm.ini:3: section 'printer' is not valid" },
        { "[printer a/b]\ndriver: marlin\n", "farm.ini:1: section 'printer a/b': printer name" },
        { "[printer a]\ndriver: marlin\nport: x\n[printer a]\n",
          "farm.ini:4: section 'printer a' appears twice" },
        { "[farm]\n[farm]\n", "farm.ini:2: section 'farm' appears twice" },
        { "listen: 1.2.3.4:5\n", "farm.ini:1: option 'listen' comes before any section" },
        { "[printer a]\ndriver: marlin\nport: x\nnozzle_mm: 0.4\nnozzle_mm: 0.6\n",
          "farm.ini:5: option 'nozzle_mm' in section 'printer a' is given twice" },
        { "[printer a]\ndriver: marlin\nport: x\nnozzle_mm: wide\n",
          "farm.ini:4: option 'nozzle_mm' in section 'printer a': 'wide' is not a number" },
        { "[printer a]\ndriver: marlin\nport: x\nnozzle_mm: 5\n", "in 0.1..2" },
        { "[printer a]\ndriver: marlin\nport: x\nbaud: 9600.5\n", "not a whole number" },
        { "[printer a]\ndriver: marlin\nport: x\nbed_size: 200, 200\n",
          "option 'bed_size' in section 'printer a': '200, 200' is not X, Y, Z" },
        { "[printer a]\ndriver: marlin\nport: x\nbed_size: 200, 200, 200, 5\n", "not X, Y, Z" },
        { "[printer a]\ndriver: marlin\nport: x\nenabled: maybe\n",
          "'maybe' is not true or false" },
        { "[printer a]\ndriver: marlin\nport: x\nallow_gcode: M600 M110\n",
          "farm.ini:4: option 'allow_gcode' in section 'printer a': 'M110' is the host's "
          "protocol" },
        { "[printer a]\ndriver: marlin\nport: x\nallow_gcode: G28\n",
          "'G28' is not a command of the G-code policy" },
        { "[printer a]\nport: x\n",
          "farm.ini:1: section 'printer a': option 'driver' is required" },
        { "[printer a]\ndriver: marlin\n", "option 'port' is required by driver marlin" },
        { "[printer a]\ndriver: repetier\n", "'repetier' is not one of marlin" },
        { "[printer a]\ndriver: bambu\n", "option 'url' is required by driver bambu" },
        { "[printer a]\ndriver: bambu\nhost: 10.0.0.5\naccess_code: 12345678\n",
          "options 'serial' and 'access_code' are required by driver bambu" },
        { "[printer a]\ndriver: bambu\nhost: 10.0.0.5\nserial: 01S00A\naccess_code: 1234\n",
          "option 'ca_file' is required by driver bambu" },
        { "[printer a]\ndriver: bambu\nhost: 10.0.0.5\nftps_port: 0\n", "in 1..65535" },
        { "[printer a]\ndriver: klipper\n", "'klipper' is not one of marlin" },
        { "[printer a]\ndriver: marlin\nport: x\nmaterial: P L A\n", "may hold only letters" },
        { "[printer a]\ndriver: octoprint\napi_key: k\n",
          "option 'url' is required by driver octoprint" },
        { "[printer a]\ndriver: octoprint\napi_key: k\n\nurl: ftp://pi\n",
          "farm.ini:5: section 'printer a': option 'url': 'ftp://pi' does not start with http" },
        { "[printer a]\ndriver: octoprint\nurl: http://:80\napi_key: k\n", "has no host" },
        { "[printer a]\ndriver: octoprint\nurl: http://pi:99999\napi_key: k\n",
          "has no port in 1..65535" },
        { "[printer a]\ndriver: octoprint\nurl: http://pi local\napi_key: k\n",
          "holds a space or control byte" },
        { "[printer a]\ndriver: octoprint\nurl: http://octopi.local\n",
          "farm.ini:1: section 'printer a': option 'api_key' is required by driver octoprint" },
        { "[printer a]\ndriver: octoprint\nurl: http://pi\napi_key: k\nuser: maker\n"
          "password: x\n",
          "driver octoprint takes no 'user'/'password'" },
        { "[printer a]\ndriver: octoprint\nurl: http://pi\napi_key: k\npoll_ms: 10\n",
          "option 'poll_ms' in section 'printer a': '10' is not a whole number in 200..60000" },
        { "[farm]\nlisten: localhost\n", "'localhost' is not ADDRESS:PORT" },
        { "[farm]\nlisten: 1.2.3.4:99999\n", "port '99999' is not in 0..65535" },
        { "[farm]\nlisten: 1.2.3.4:-1\n", "port '-1' is not in 0..65535" },
        { "[farm]\nlisten: example.com:80\n", "is not an IPv4 address" },
        { "[farm]\napi_keys: short\n", "each key must be 16..128 characters" },
        { "[farm]\napi_keys: aaaaaaaaaaaaaaaa\napi_keys_readonly: aaaaaaaaaaaaaaaa\n",
          "farm.ini:3: option 'api_keys_readonly' in section 'farm': key given twice" },
        { "[farm]\napi_keys: aaaaaaaaaaaaaaa$\n", "keys may hold only" },
        { "[farm]\nupload_max_mb: 0\n", "upload_max_mb" },
        { "[farm]\ngram_seconds: -1\n", "option 'gram_seconds' in section 'farm'" },
        { "[farm]\njust words\n", "farm.ini:2: syntax error" },
        { "[farm\n", "farm.ini:1: section header lacks ']'" },
        { "[farm]\ndata_dir: /x\0y\n", "" /* NUL handled: text is cut at strlen */ },
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        int rc = parse(&c, bad[i].text, &err);
        if (!bad[i].msg[0]) {
            farmcfg_release(&c);
            continue;
        }
        if (rc != SF_EINVAL || !strstr(err.msg, bad[i].msg)) {
            t_fail(__FILE__, __LINE__, "case %zu: rc %d, message \"%s\" lacks \"%s\"", i, rc,
                   err.msg, bad[i].msg);
            return;
        }
        T_EQ_INT(c.n_printers, 0); /* released on error */
    }
}

T_CASE(farmcfg_long_lines_and_binary_refused)
{
    struct farmcfg c;
    struct sf_err err;
    char text[600];
    memset(text, 'x', sizeof(text));
    memcpy(text, "[farm]\ndata_dir: ", 17);
    text[sizeof(text) - 1] = '\0';
    T_ERR(parse(&c, text, &err), SF_EINVAL, &err, "farm.ini:2: line is longer than");
    const char bin[] = "[farm]\nlisten: 1.2.3.4:5\0junk\n";
    farmcfg_init(&c);
    T_ERR(farmcfg_parse(&c, bin, sizeof(bin) - 1, "farm.ini", &err), SF_EINVAL, &err,
          "farm.ini:2: line holds a NUL byte");
    farmcfg_init(&c);
    T_ERR(farmcfg_load(&c, "/nonexistent/farm.ini", &err), SF_EIO, &err, "farm.ini");
}

T_CASE(farmcfg_documented_file_parses_and_documents_everything)
{
    struct buf b;
    struct sf_err err;
    buf_init(&b, 1 << 20);
    T_OK(buf_read_file(&b, "config/farm.ini", &err), &err);
    struct farmcfg c;
    farmcfg_init(&c);
    T_OK(farmcfg_parse(&c, b.data, b.len, "config/farm.ini", &err), &err);
    T_EQ_INT(c.n_printers, 0);
    T_EQ_INT(c.listen_port, 7420);
    farmcfg_release(&c);
    /* Uncomment every "#key: value" and "#[section]" line: still valid. */
    struct buf u;
    buf_init(&u, 0);
    const char *p = b.data;
    while (*p) {
        const char *nl = strchr(p, '\n');
        size_t n = nl ? (size_t)(nl - p + 1) : strlen(p);
        bool opt = p[0] == '#' && (p[1] == '[' || (p[1] >= 'a' && p[1] <= 'z'));
        const char *colon = memchr(p, ':', n);
        if (opt && p[1] != '[' && (!colon || memchr(p, ' ', (size_t)(colon - p))))
            opt = false; /* prose, not "#key:" */
        buf_append(&u, opt ? p + 1 : p, opt ? n - 1 : n);
        p += n;
    }
    farmcfg_init(&c);
    T_OK(farmcfg_parse(&c, u.data, u.len, "farm.ini (uncommented)", &err), &err);
    T_EQ_INT(c.n_printers, 1);
    T_EQ_STR(link_of(&c.printers[0]).port, "/dev/ttyUSB0");
    farmcfg_release(&c);
    /* every option the parser knows is documented */
    bool printer;
    const char *name;
    for (size_t i = 0; (name = farmcfg_option_name(i, &printer)); i++) {
        char needle[64];
        snprintf(needle, sizeof(needle), "\n#%s:", name);
        if (!strstr(b.data, needle)) {
            t_fail(__FILE__, __LINE__, "option '%s' is not documented in config/farm.ini", name);
            break;
        }
    }
    buf_release(&u);
    buf_release(&b);
}

T_CASE(farmcfg_notify_sections)
{
    struct farmcfg c;
    struct sf_err err;
    T_OK(parse(&c,
               "[notify chat]\nurl: https://discord.example/api/webhooks/1/abc\nformat: discord\n"
               "events: job-done, bed-clear\nretries: 2\n"
               "[notify mail]\nurl: smtps://relay.example:465\nfrom: farm@example.org\n"
               "to: a@example.org, b@example.org\nuser: farm\npassword: pw\n"
               "[notify plain]\nurl: http://10.0.0.9:8123/\n",
               &err),
         &err);
    T_EQ_INT(c.n_notify, 3);
    T_EQ_STR(c.notify[0].name, "chat");
    T_EQ_INT(c.notify[0].format, NOTIFY_FMT_DISCORD);
    T_EQ_INT(c.notify[0].events, NOTIFY_JOB_DONE | NOTIFY_BED_CLEAR);
    T_EQ_INT(c.notify[0].retries, 2);
    T_TRUE(notifycfg_has_secret(&c.notify[0])); /* the url's path is its key */
    T_TRUE(notifycfg_is_mail(&c.notify[1]) && notifycfg_has_secret(&c.notify[1]));
    T_EQ_INT(c.notify[2].events, NOTIFY_ALL);
    T_EQ_INT(c.notify[2].retries, 4);
    T_TRUE(!notifycfg_has_secret(&c.notify[2]));
    farmcfg_release(&c);
    T_EQ_INT(c.n_notify, 0);
    static const char *const bad[][2] = {
        { "[notify a]\nurl: http://h/\nurl: http://h/\n",
          "farm.ini:3: section 'notify a': option 'url' is given twice" },
        { "[notify a]\nurl: http://h/\n[notify a]\nurl: http://h/\n",
          "farm.ini:3: section 'notify a' appears twice" },
        { "[notify a]\nurl: http://h/\nformat: template\n",
          "farm.ini:1: section 'notify a': options 'format: template' and 'template' go together" },
        { "[notify a]\nurl: http://h/\nfrom: x@y\n",
          "farm.ini:1: section 'notify a': options 'from', 'to', 'user', 'password' and "
          "'starttls' are for smtp:// targets, not webhooks" },
        { "[notify a]\nurl: smtp://h\nfrom: x@y\nto: nobody\n",
          "farm.ini:1: section 'notify a': option 'to': 'nobody' is not an address name@host" },
        { "[notify a]\nurl: smtp://h\nfrom: x@y\nto: a@b\ntoken: t\n",
          "farm.ini:1: section 'notify a': options 'token', 'format' and 'template' are for "
          "webhooks, not smtp:// targets" },
        { "[notify a]\nurl: http://\n",
          "farm.ini:1: section 'notify a': option 'url': it has no host" },
        { "[notify a]\nurl: http://h/\ntimeout_s: 0\n",
          "farm.ini:3: section 'notify a': option 'timeout_s': '0' is not a whole number in "
          "1..300" },
        { "[notify]\n", "farm.ini:1: section 'notify' is not valid (expected 'farm', 'printer "
                        "NAME' or 'notify NAME')" },
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        T_EQ_INT(parse(&c, bad[i][0], &err), SF_EINVAL);
        T_EQ_STR(err.msg, bad[i][1]);
    }
}

/* farmcfg_option_fn: the options as a section's body, secrets marked. */
static void
append_option(void *ud, const char *name, const char *value, bool secret)
{
    buf_printf(ud, "%s: %s%s\n", name, value, secret ? " " : "");
}

/*
 * A printer section's body (the run-time printers' path, farm.h): checked
 * by the file's rules, messages without a file:line; each option written
 * back as text (farmcfg_printer_each) parses to the same printer.
 */
T_CASE(farmcfg_printer_body_round_trip)
{
    struct farmcfg_printer p, q;
    struct sf_err err;
    const char *body =
        "driver: bambu\nhost: 192.168.1.20\nserial: 01S00A\naccess_code: 12345678\n"
        "ca_file: /etc/bbl.pem\nnozzle_mm: 0.6\nbed_size: 256, 256, 250.5\nattended: yes\n"
        "allow_gcode: M600\ngroup: big\n";
    T_OK(farmcfg_printer_parse(&p, "x1", body, strlen(body), &err), &err);
    T_EQ_STR(p.name, "x1");
    T_EQ_DBL(p.bed_mm[2], 250.5, 0);
    T_EQ_STR(link_of(&p).url, "mqtts://192.168.1.20");
    struct buf b;
    buf_init(&b, 1 << 16);
    farmcfg_printer_each(&p, append_option, &b);
    T_TRUE(strstr(b.data, "host: 192.168.1.20\n") != NULL);     /* without the mqtts:// it gets */
    T_TRUE(strstr(b.data, "access_code: 12345678 \n") != NULL); /* marked secret */
    T_TRUE(strstr(b.data, "attended: true\n") != NULL);
    T_OK(farmcfg_printer_parse(&q, "x1", b.data, b.len, &err), &err);
    T_EQ_STR(link_of(&q).url, link_of(&p).url);
    T_EQ_STR(link_of(&q).api_key, "12345678");
    T_EQ_STR(q.allow_gcode, p.allow_gcode);
    T_EQ_STR(q.group, "big");
    T_TRUE(q.attended && q.nozzle_mm == 0.6 && q.bed_mm[0] == 256);
    buf_release(&b);
    static const char *const bad[][3] = {
        { "a", "driver: marlin\nnozzle_mm: 9\nport: x\n",
          "option 'nozzle_mm' in section 'printer a': '9' is not a number in 0.1..2" },
        { "a", "driver: marlin\n",
          "section 'printer a': option 'port' is required by driver "
          "marlin" },
        { "a", "driver: marlin\nport: x\n[farm]\nlisten: 0.0.0.0:1\n",
          "section 'printer a': a section header in it" },
        { "a b", "driver: marlin\nport: x\n",
          "printer name 'a b' must be 1..63 letters, digits, '-', '_', '.'" },
        { "a]", "driver: marlin\nport: x\n",
          "printer name 'a]' must be 1..63 letters, digits, '-', '_', '.'" },
        /* a path step to HTTP clients: /api/printers/.. could not reach it again */
        { "..", "driver: marlin\nport: x\n", "printer name '..' must not start with '.'" },
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        T_EQ_INT(farmcfg_printer_parse(&p, bad[i][0], bad[i][1], strlen(bad[i][1]), &err),
                 SF_EINVAL);
        T_EQ_STR(err.msg, bad[i][2]);
    }
}
