/*
 * test_gcode3mf.c - the .gcode.3mf package a Bambu job is uploaded in.
 *
 * The package is read back by Python's zipfile (Debian's /usr/bin/python3),
 * an implementation independent of the minizip that wrote it: every entry
 * the firmware reads is there, the archive's CRCs hold, plate_1.gcode is
 * byte for byte our G-code, and its .md5 sidecar is the uppercase MD5 of
 * it with no newline.  A job larger than one step is packed in steps.
 */
#include <stdlib.h>
#include <unistd.h>

#include "../../drivers/bambu/gcode3mf.h"
#include "../t.h"

#define PY "/usr/bin/python3"

static const char check_py[] =
    "import sys, zipfile, hashlib\n"
    "z = zipfile.ZipFile(sys.argv[1])\n"
    "bad = z.testzip()\n"
    "assert bad is None, 'bad CRC in %s' % bad\n"
    "need = ['[Content_Types].xml', '_rels/.rels', '3D/3dmodel.model',\n"
    "        'Metadata/plate_1.gcode', 'Metadata/plate_1.gcode.md5',\n"
    "        'Metadata/model_settings.config', 'Metadata/_rels/model_settings.config.rels',\n"
    "        'Metadata/slice_info.config', 'Metadata/plate_1.json']\n"
    "names = z.namelist()\n"
    "for n in need: assert n in names, 'missing ' + n\n"
    "g = z.read('Metadata/plate_1.gcode')\n"
    "assert g == open(sys.argv[2], 'rb').read(), 'plate_1.gcode differs from the job'\n"
    "md5 = z.read('Metadata/plate_1.gcode.md5').decode()\n"
    "assert md5 == hashlib.md5(g).hexdigest().upper(), 'sidecar ' + md5\n"
    "assert md5 == sys.argv[3], 'writer reported ' + sys.argv[3]\n"
    "import xml.dom.minidom as m\n"
    "for n in names:\n"
    "    if n.endswith(('.xml', '.rels', '.model', '.config')): m.parseString(z.read(n))\n"
    "    if n.endswith('.json'): __import__('json').loads(z.read(n))\n"
    "ms = z.read('Metadata/model_settings.config').decode()\n"
    "assert 'value=\"Metadata/plate_1.gcode\"' in ms, ms\n"
    "si = z.read('Metadata/slice_info.config').decode()\n"
    "assert 'key=\"prediction\" value=\"3600\"' in si, si\n"
    "whole = hashlib.md5(open(sys.argv[1], 'rb').read()).hexdigest().upper()\n"
    "assert whole == sys.argv[4], 'package md5 %s != %s' % (whole, sys.argv[4])\n"
    "print('ok')\n";

static int
run_check(const char *pkg, const char *gcode, const char *md5, const char *whole)
{
    char script[512], cmd[2048];
    snprintf(script, sizeof(script), "%s/check.py", t_tmpdir());
    FILE *f = fopen(script, "w");
    if (!f)
        return -1;
    fputs(check_py, f);
    fclose(f);
    snprintf(cmd, sizeof(cmd), PY " %s '%s' '%s' %s %s 2>&1", script, pkg, gcode, md5, whole);
    FILE *p = popen(cmd, "r");
    char out[1024] = "";
    size_t n = p ? fread(out, 1, sizeof(out) - 1, p) : 0;
    out[n] = '\0';
    int rc = p ? pclose(p) : -1;
    if (rc != 0 || strcmp(out, "ok\n") != 0) {
        fprintf(stderr, "check.py: %s", out);
        return -1;
    }
    return 0;
}

static void
write_gcode(const char *path, int lines)
{
    FILE *f = fopen(path, "w");
    fprintf(f, "; test job\nG28\nM104 S205\n");
    for (int i = 0; i < lines; i++)
        fprintf(f, "G1 X%d.%03d Y%d E%d.5 F1800\n", i % 200, i % 1000, (i * 7) % 200, i);
    fprintf(f, "M104 S0\n");
    fclose(f);
}

static void
pack_and_check(int lines, size_t step)
{
    T_SKIP_UNLESS(access(PY, X_OK) == 0, PY " not found");
    char gcode[512], pkg[512];
    snprintf(gcode, sizeof(gcode), "%s/job%d.gcode", t_tmpdir(), lines);
    snprintf(pkg, sizeof(pkg), "%s/job%d.gcode.3mf", t_tmpdir(), lines);
    write_gcode(gcode, lines);
    struct gcode3mf_meta meta = { .title = "cube <1>", .print_s = 3600, .filament_g = 12.5 };
    struct sf_err err;
    struct gcode3mf *w = gcode3mf_new(pkg, gcode, &meta, &err);
    T_TRUE(w != NULL);
    int rc, steps = 0;
    while ((rc = gcode3mf_step(w, step, &err)) == 1)
        steps++;
    T_OK(rc, &err);
    T_EQ_INT(gcode3mf_done(w), gcode3mf_total(w));
    if (step)
        T_TRUE(steps >= (int)(gcode3mf_total(w) / step) - 1);
    char md5[33], whole[33];
    snprintf(md5, sizeof(md5), "%s", gcode3mf_gcode_md5(w));
    gcode3mf_free(w);
    T_OK(gcode3mf_file_md5(pkg, whole, &err), &err);
    T_EQ_INT(run_check(pkg, gcode, md5, whole), 0);
}

T_CASE(gcode3mf_small_one_step)
{
    pack_and_check(10, 0);
}

T_CASE(gcode3mf_large_in_steps)
{
    pack_and_check(60000, 100000); /* ~1.7 MB in 100 kB steps */
}

T_CASE(gcode3mf_empty_gcode)
{
    pack_and_check(0, 0);
}

T_CASE(gcode3mf_missing_gcode_is_an_error)
{
    struct sf_err err;
    char pkg[512];
    snprintf(pkg, sizeof(pkg), "%s/none.gcode.3mf", t_tmpdir());
    T_TRUE(gcode3mf_new(pkg, "/nonexistent/job.gcode", NULL, &err) == NULL);
    T_TRUE(strstr(err.msg, "/nonexistent/job.gcode") != NULL);
    T_TRUE(access(pkg, F_OK) != 0);
}
