/*
 * gcode3mf.c - the .gcode.3mf package of a Bambu job (gcode3mf.h).
 *
 * Why: Bambu printers start a LAN job with the project_file command, which
 * names an entry inside an uploaded 3MF; plain .gcode (gcode_file) is
 * unreliable on P1/A1 (BAMBU-LAN.md section 2).  The package mirrors what
 * Bambu Studio and Cura's BambuLabVariant write, minus geometry and
 * thumbnails.
 *
 * Design: minizip (already linked for the 3MF loader) writes the zip; the
 * G-code entry is deflated at level 1 (G-code shrinks about 4x even so, and
 * level 1 keeps a megabyte step near 10 ms) while the same bytes feed the
 * MD5 for the sidecar, which is written after it.  Zip64 is switched on per
 * entry when the G-code passes 4 GiB.  The small XML/JSON entries are fixed
 * text with our numbers.
 *
 * Thread: any; a writer belongs to one thread.
 */
#include "gcode3mf.h"

#include <errno.h>
#include <minizip/zip.h>
#include <openssl/evp.h>
#include <stdbool.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/mem.h"

#define GCODE_ENTRY "Metadata/plate_1.gcode"
#define STEP_CHUNK  (64 * 1024)

struct gcode3mf {
    zipFile zip;          /* the package being written; NULL once closed */
    FILE *in;             /* the G-code */
    char *out_path;       /* removed by free() unless complete */
    EVP_MD_CTX *md5;      /* MD5 of the G-code so far */
    uint64_t done;        /* G-code bytes copied */
    uint64_t total;       /* G-code file size */
    bool complete;        /* every entry written and the zip closed */
    char md5_hex[33];     /* the G-code's MD5, uppercase */
    char title[128];      /* ASCII title for slice_info */
    double print_s;       /* predicted time, s */
    double filament_g;    /* predicted filament, g */
    double nozzle_mm;     /* nozzle diameter */
    char client[64];      /* client name for the header */
    unsigned char *chunk; /* STEP_CHUNK bytes of copy buffer */
};

static void
hex_upper(const unsigned char *d, unsigned n, char *out)
{
    static const char digits[] = "0123456789ABCDEF";
    for (unsigned i = 0; i < n; i++) {
        out[2 * i] = digits[d[i] >> 4];
        out[2 * i + 1] = digits[d[i] & 15];
    }
    out[2 * n] = '\0';
}

/* Title safe for XML and the printer's screen: printable ASCII, no markup. */
static void
safe_title(const char *in, char *out, size_t n)
{
    size_t j = 0;
    for (; in && *in && j + 1 < n; in++) {
        unsigned char c = (unsigned char)*in;
        out[j++] = (c >= 0x20 && c < 0x7f && !strchr("<>&\"'", c)) ? (char)c : '_';
    }
    out[j] = '\0';
}

static int
open_entry(struct gcode3mf *w, const char *name, int level, bool zip64, struct sf_err *err)
{
    zip_fileinfo zi;
    memset(&zi, 0, sizeof(zi));
    time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    zi.tmz_date.tm_sec = (uInt)tm.tm_sec;
    zi.tmz_date.tm_min = (uInt)tm.tm_min;
    zi.tmz_date.tm_hour = (uInt)tm.tm_hour;
    zi.tmz_date.tm_mday = (uInt)tm.tm_mday;
    zi.tmz_date.tm_mon = (uInt)tm.tm_mon;
    zi.tmz_date.tm_year = (uInt)tm.tm_year + 1900;
    if (zipOpenNewFileInZip3_64(w->zip, name, &zi, NULL, 0, NULL, 0, NULL, level ? Z_DEFLATED : 0,
                                level, 0, -MAX_WBITS, DEF_MEM_LEVEL, Z_DEFAULT_STRATEGY, NULL, 0,
                                zip64 ? 1 : 0) != ZIP_OK)
        return sf_err_set(err, SF_EIO, "3mf '%s': cannot add entry '%s'", w->out_path, name);
    return SF_OK;
}

static int
write_entry(struct gcode3mf *w, const char *name, const char *text, size_t len, struct sf_err *err)
{
    int rc = open_entry(w, name, Z_DEFAULT_COMPRESSION, false, err);
    if (rc < 0)
        return rc;
    if (len && zipWriteInFileInZip(w->zip, text, (unsigned)len) != ZIP_OK) {
        zipCloseFileInZip(w->zip);
        return sf_err_set(err, SF_EIO, "3mf '%s': cannot write entry '%s'", w->out_path, name);
    }
    if (zipCloseFileInZip(w->zip) != ZIP_OK)
        return sf_err_set(err, SF_EIO, "3mf '%s': cannot close entry '%s'", w->out_path, name);
    return SF_OK;
}

static int
write_text(struct gcode3mf *w, const char *name, const struct buf *b, struct sf_err *err)
{
    return write_entry(w, name, b->data ? b->data : "", b->len, err);
}

/* Everything before the G-code: package structure and an empty model. */
static int
write_head(struct gcode3mf *w, struct sf_err *err)
{
    static const char content_types[] =
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
        "<Types xmlns=\"http://schemas.openxmlformats.org/package/2006/content-types\">\n"
        " <Default Extension=\"rels\" "
        "ContentType=\"application/vnd.openxmlformats-package.relationships+xml\"/>\n"
        " <Default Extension=\"model\" "
        "ContentType=\"application/vnd.ms-package.3dmanufacturing-3dmodel+xml\"/>\n"
        " <Default Extension=\"png\" ContentType=\"image/png\"/>\n"
        " <Default Extension=\"gcode\" ContentType=\"text/x.gcode\"/>\n"
        "</Types>\n";
    static const char rels[] =
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
        "<Relationships xmlns=\"http://schemas.openxmlformats.org/package/2006/relationships\">\n"
        " <Relationship Target=\"/3D/3dmodel.model\" Id=\"rel-1\" "
        "Type=\"http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel\"/>\n"
        "</Relationships>\n";
    int rc = write_entry(w, "[Content_Types].xml", content_types, sizeof(content_types) - 1, err);
    if (rc == SF_OK)
        rc = write_entry(w, "_rels/.rels", rels, sizeof(rels) - 1, err);
    if (rc < 0)
        return rc;
    struct buf b;
    buf_init(&b, 1 << 16);
    if (buf_printf(&b,
                   "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
                   "<model unit=\"millimeter\" xml:lang=\"en-US\" "
                   "xmlns=\"http://schemas.microsoft.com/3dmanufacturing/core/2015/02\" "
                   "xmlns:BambuStudio=\"http://schemas.bambulab.com/package/2021\">\n"
                   " <metadata name=\"Application\">%s</metadata>\n"
                   " <metadata name=\"BambuStudio:3mfVersion\">1</metadata>\n"
                   " <metadata name=\"Title\">%s</metadata>\n"
                   " <resources/>\n <build/>\n</model>\n",
                   w->client, w->title) < 0) {
        buf_release(&b);
        return sf_err_set(err, SF_ENOMEM, "3mf '%s': out of memory", w->out_path);
    }
    rc = write_text(w, "3D/3dmodel.model", &b, err);
    buf_release(&b);
    if (rc < 0)
        return rc;
    return open_entry(w, GCODE_ENTRY, 1, w->total >= 0xffffffffu, err);
}

/* Everything after the G-code: its MD5 and the metadata naming it. */
static int
write_tail(struct gcode3mf *w, struct sf_err *err)
{
    int rc = write_entry(w, GCODE_ENTRY ".md5", w->md5_hex, 32, err);
    if (rc < 0)
        return rc;
    struct buf b;
    buf_init(&b, 1 << 16);
    int prc = buf_printf(&b,
                         "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
                         "<config>\n"
                         "  <plate>\n"
                         "    <metadata key=\"plater_id\" value=\"1\"/>\n"
                         "    <metadata key=\"plater_name\" value=\"%s\"/>\n"
                         "    <metadata key=\"locked\" value=\"false\"/>\n"
                         "    <metadata key=\"gcode_file\" value=\"" GCODE_ENTRY "\"/>\n"
                         "  </plate>\n"
                         "</config>\n",
                         w->title);
    if (prc == SF_OK)
        rc = write_text(w, "Metadata/model_settings.config", &b, err);
    buf_reset(&b);
    if (prc == SF_OK && rc == SF_OK)
        prc = buf_printf(&b,
                         "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
                         "<Relationships "
                         "xmlns=\"http://schemas.openxmlformats.org/package/2006/relationships\">\n"
                         " <Relationship Target=\"/" GCODE_ENTRY "\" Id=\"rel-1\" "
                         "Type=\"http://schemas.bambulab.com/package/2021/gcode\"/>\n"
                         "</Relationships>\n");
    if (prc == SF_OK && rc == SF_OK)
        rc = write_text(w, "Metadata/_rels/model_settings.config.rels", &b, err);
    buf_reset(&b);
    if (prc == SF_OK && rc == SF_OK)
        prc = buf_printf(&b,
                         "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
                         "<config>\n"
                         "  <header>\n"
                         "    <header_item key=\"X-BBL-Client-Type\" value=\"slicer\"/>\n"
                         "    <header_item key=\"X-BBL-Client-Version\" value=\"%s\"/>\n"
                         "  </header>\n"
                         "  <plate>\n"
                         "    <metadata key=\"index\" value=\"1\"/>\n"
                         "    <metadata key=\"printer_model_id\" value=\"\"/>\n"
                         "    <metadata key=\"nozzle_diameters\" value=\"%.2f\"/>\n"
                         "    <metadata key=\"prediction\" value=\"%.0f\"/>\n"
                         "    <metadata key=\"weight\" value=\"%.2f\"/>\n"
                         "    <metadata key=\"outside\" value=\"false\"/>\n"
                         "    <metadata key=\"support_used\" value=\"false\"/>\n"
                         "    <metadata key=\"label_object_enabled\" value=\"false\"/>\n"
                         "  </plate>\n"
                         "</config>\n",
                         w->client, w->nozzle_mm, w->print_s, w->filament_g);
    if (prc == SF_OK && rc == SF_OK)
        rc = write_text(w, "Metadata/slice_info.config", &b, err);
    buf_reset(&b);
    if (prc == SF_OK && rc == SF_OK)
        prc = buf_printf(&b,
                         "{\n  \"version\": 2,\n  \"nozzle_diameter\": %.2f,\n"
                         "  \"bbox_objects\": [],\n  \"bed_type\": \"auto\"\n}\n",
                         w->nozzle_mm);
    if (prc == SF_OK && rc == SF_OK)
        rc = write_text(w, "Metadata/plate_1.json", &b, err);
    buf_release(&b);
    if (prc < 0)
        return sf_err_set(err, SF_ENOMEM, "3mf '%s': out of memory", w->out_path);
    return rc;
}

struct gcode3mf *
gcode3mf_new(const char *out_path, const char *gcode_path, const struct gcode3mf_meta *meta,
             struct sf_err *err)
{
    struct gcode3mf *w = mem_calloc(1, sizeof(*w));
    if (!w) {
        sf_err_set(err, SF_ENOMEM, "3mf: out of memory");
        return NULL;
    }
    w->out_path = mem_strdup(out_path);
    w->chunk = mem_alloc(STEP_CHUNK);
    w->md5 = EVP_MD_CTX_new();
    if (!w->out_path || !w->chunk || !w->md5 || EVP_DigestInit_ex(w->md5, EVP_md5(), NULL) != 1) {
        sf_err_set(err, SF_ENOMEM, "3mf: out of memory");
        goto fail;
    }
    safe_title(meta && meta->title ? meta->title : "slimfarm", w->title, sizeof(w->title));
    safe_title(meta && meta->client ? meta->client : "slimfarm", w->client, sizeof(w->client));
    w->print_s = meta && meta->print_s > 0 ? meta->print_s : 0;
    w->filament_g = meta && meta->filament_g > 0 ? meta->filament_g : 0;
    w->nozzle_mm = meta && meta->nozzle_mm > 0 ? meta->nozzle_mm : 0.4;
    w->in = fopen(gcode_path, "rb");
    struct stat st;
    if (!w->in || fstat(fileno(w->in), &st) < 0) {
        sf_err_sys(err, "3mf: cannot read G-code '%s'", gcode_path);
        goto fail;
    }
    w->total = (uint64_t)st.st_size;
    w->zip = zipOpen64(out_path, APPEND_STATUS_CREATE);
    if (!w->zip) {
        sf_err_sys(err, "3mf: cannot create '%s'", out_path);
        goto fail;
    }
    if (write_head(w, err) < 0)
        goto fail;
    return w;
fail:
    gcode3mf_free(w);
    return NULL;
}

int
gcode3mf_step(struct gcode3mf *w, size_t max_bytes, struct sf_err *err)
{
    if (w->complete)
        return 0;
    if (!w->zip)
        return sf_err_set(err, SF_EIO, "3mf '%s': writer failed earlier", w->out_path);
    size_t budget = max_bytes ? max_bytes : SIZE_MAX;
    while (budget > 0) {
        size_t want = budget < STEP_CHUNK ? budget : STEP_CHUNK;
        size_t n = fread(w->chunk, 1, want, w->in);
        if (n > 0) {
            if (zipWriteInFileInZip(w->zip, w->chunk, (unsigned)n) != ZIP_OK)
                goto io;
            EVP_DigestUpdate(w->md5, w->chunk, n);
            w->done += n;
            budget -= n;
        }
        if (n < want) {
            if (ferror(w->in))
                goto io;
            break; /* end of the G-code */
        }
    }
    if (budget == 0 && !feof(w->in) && w->done < w->total)
        return 1;
    if (zipCloseFileInZip(w->zip) != ZIP_OK)
        goto io;
    unsigned char d[EVP_MAX_MD_SIZE];
    unsigned dn = 0;
    EVP_DigestFinal_ex(w->md5, d, &dn);
    hex_upper(d, dn, w->md5_hex);
    int rc = write_tail(w, err);
    int crc = zipClose(w->zip, NULL);
    w->zip = NULL;
    if (rc < 0)
        return rc;
    if (crc != ZIP_OK)
        return sf_err_set(err, SF_EIO, "3mf '%s': cannot finish the zip", w->out_path);
    w->complete = true;
    return 0;
io:
    zipClose(w->zip, NULL);
    w->zip = NULL;
    return sf_err_set(err, SF_EIO, "3mf '%s': write failed after %llu bytes of G-code", w->out_path,
                      (unsigned long long)w->done);
}

uint64_t
gcode3mf_done(const struct gcode3mf *w)
{
    return w->done;
}

uint64_t
gcode3mf_total(const struct gcode3mf *w)
{
    return w->total;
}

const char *
gcode3mf_gcode_md5(const struct gcode3mf *w)
{
    return w->md5_hex;
}

void
gcode3mf_free(struct gcode3mf *w)
{
    if (!w)
        return;
    if (w->zip)
        zipClose(w->zip, NULL);
    if (w->in)
        fclose(w->in);
    if (!w->complete && w->out_path)
        unlink(w->out_path);
    EVP_MD_CTX_free(w->md5);
    free(w->chunk);
    free(w->out_path);
    free(w);
}

int
gcode3mf_write(const char *out_path, const char *gcode_path, const struct gcode3mf_meta *meta,
               char *md5_out, struct sf_err *err)
{
    struct gcode3mf *w = gcode3mf_new(out_path, gcode_path, meta, err);
    if (!w)
        return err ? err->code : SF_EIO;
    int rc = gcode3mf_step(w, 0, err);
    if (rc == 0 && md5_out)
        memcpy(md5_out, w->md5_hex, 33);
    gcode3mf_free(w);
    return rc < 0 ? rc : SF_OK;
}

int
gcode3mf_file_md5(const char *path, char *out, struct sf_err *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return sf_err_sys(err, "md5: cannot read '%s'", path);
    EVP_MD_CTX *c = EVP_MD_CTX_new();
    unsigned char chunk[16384];
    int rc = SF_OK;
    if (!c || EVP_DigestInit_ex(c, EVP_md5(), NULL) != 1) {
        rc = sf_err_set(err, SF_ENOMEM, "md5: out of memory");
        goto out;
    }
    size_t n;
    while ((n = fread(chunk, 1, sizeof(chunk), f)) > 0)
        EVP_DigestUpdate(c, chunk, n);
    if (ferror(f)) {
        rc = sf_err_sys(err, "md5: read error in '%s'", path);
        goto out;
    }
    unsigned char d[EVP_MAX_MD_SIZE];
    unsigned dn = 0;
    EVP_DigestFinal_ex(c, d, &dn);
    hex_upper(d, dn, out);
out:
    EVP_MD_CTX_free(c);
    fclose(f);
    return rc;
}
