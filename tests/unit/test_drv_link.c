/*
 * test_drv_link.c - the kinds' link option tables (drivers/drv.c) and what
 * drv_link.h makes of them: every option named once, its default in its
 * range, all of them fitting struct drv_link; a section's values make the
 * driver's config by the kind's rows (defaults, bambu's host, options the
 * kind does not take left out); a reload's comparison sees a change of any
 * option; secrets are never shown; and every kind names the G-code rules
 * drv_job_scan applies.
 */
#include "../../drivers/drv_link.h"
#include "../t.h"

T_CASE(drv_link_tables_are_sound)
{
    const struct drv_option *o;
    size_t n = 0, text = 0;
    for (size_t i = 0; (o = drv_link_option_at(i)); i++, n++) {
        T_TRUE(drv_link_option(o->name) == o); /* one row per name, whichever kinds share it */
        if (o->type == DRV_OPT_INT) {
            if (o->def != 0 && (o->def < o->lo || o->def > o->hi))
                t_fail(__FILE__, __LINE__, "option '%s': default %d not in %d..%d", o->name, o->def,
                       o->lo, o->hi);
        } else if (o->type != DRV_OPT_BOOL) {
            T_TRUE(o->size > 1);
            text += o->size + (o->prefix ? strlen(o->prefix) : 0);
        }
        T_TRUE(o->off + sizeof(int) <= sizeof(struct drv_config));
    }
    T_TRUE(n >= 15);
    T_TRUE(n <= SF_LINK_OPTS_MAX);
    T_TRUE(text <= SF_LINK_TEXT_MAX); /* every option once at its longest fits */
    const struct drv_kind *k;
    for (size_t i = 0; (k = drv_kind_at(i)); i++) {
        T_TRUE(drv_kind_option(k, 0) != NULL);
        /* files are checked before their printer is known (drv_job_scan): a kind with other
           rules needs its scans routed by kind first */
        T_EQ_INT(k->gcode, DRV_JOB_RULES);
    }
    T_EQ_STR(gcheck_rules_name(DRV_JOB_RULES), "marlin");
    /* the secrets: what the API, metrics and logs never show */
    static const char *const secret[] = { "api_key", "password", "access_code" };
    for (size_t i = 0; i < 3; i++)
        T_TRUE(drv_link_option(secret[i])->flags & DRV_OPT_SECRET);
    T_TRUE(!(drv_link_option("url")->flags & DRV_OPT_SECRET));
}

static void
set(struct drv_link *l, const char *name, const char *text, int num)
{
    struct sf_err err;
    T_OK(drv_link_set(l, drv_link_option(name), text, num, 7, &err), &err);
}

T_CASE(drv_link_config_follows_the_kind)
{
    struct drv_link l;
    drv_link_init(&l);
    set(&l, "port", "/dev/ttyACM0", 0);
    set(&l, "url", "http://not.for.marlin", 0);
    set(&l, "rx_buffer", "", 256);
    struct drv_config dc = { 0 };
    drv_link_config(&l, drv_kind_find("marlin"), &dc);
    T_EQ_STR(dc.port, "/dev/ttyACM0");
    T_EQ_INT(dc.baud, 115200); /* defaults */
    T_EQ_INT(dc.buffer_lines, 4);
    T_EQ_INT(dc.rx_buffer, 256);
    T_TRUE(dc.url == NULL); /* marlin takes no url */
    struct sf_err err;
    T_ERR(drv_link_set(&l, drv_link_option("port"), "x", 0, 9, &err), SF_EINVAL, &err,
          "option 'port' is given twice");
    T_EQ_INT(drv_link_get(&l, drv_link_option("url"))->line, 7);

    /* bambu: host makes the url unless url is given, in either order */
    const struct drv_kind *bambu = drv_kind_find("bambu");
    drv_link_init(&l);
    set(&l, "host", "10.0.0.5", 0);
    set(&l, "access_code", "12345678", 0);
    set(&l, "tls_insecure", "", 1);
    dc = (struct drv_config){ 0 };
    drv_link_config(&l, bambu, &dc);
    T_EQ_STR(dc.url, "mqtts://10.0.0.5");
    T_EQ_STR(dc.api_key, "12345678");
    T_EQ_STR(dc.serial, "");
    T_TRUE(dc.tls_insecure);
    T_EQ_INT(dc.ftps_port, 0); /* the driver's 990 */
    char why[200] = "";
    T_TRUE(bambu->check(&dc, why, sizeof(why)) < 0);
    T_EQ_STR(why, "options 'serial' and 'access_code' are required by driver bambu");
    set(&l, "url", "mqtts://10.0.0.6:8884", 0);
    set(&l, "serial", "01S00A", 0);
    drv_link_config(&l, bambu, &dc);
    T_EQ_STR(dc.url, "mqtts://10.0.0.6:8884");
    T_EQ_INT(bambu->check(&dc, why, sizeof(why)), 0);
}

T_CASE(drv_link_diff_sees_every_option_and_shows_no_secret)
{
    const struct drv_kind *k = drv_kind_find("prusalink");
    struct drv_link a, b;
    drv_link_init(&a);
    set(&a, "url", "http://mk4.local", 0);
    set(&a, "user", "maker", 0);
    set(&a, "password", "old-pw", 0);
    b = a; /* plain data: copies by value */
    T_TRUE(drv_link_diff(k, &a, &b) == NULL);
    drv_link_init(&b);
    set(&b, "password", "new-pw", 0); /* order given does not matter, values do */
    set(&b, "user", "maker", 0);
    set(&b, "url", "http://mk4.local", 0);
    const struct drv_option *o = drv_link_diff(k, &a, &b);
    T_TRUE(o != NULL);
    T_EQ_STR(o->name, "password");
    char shown[64];
    drv_link_show(&b, k, o, shown, sizeof(shown));
    T_EQ_STR(shown, "(secret)");
    drv_link_show(&b, k, drv_link_option("url"), shown, sizeof(shown));
    T_EQ_STR(shown, "http://mk4.local");
    /* a default given explicitly is no change; another poll period is */
    b = a;
    set(&b, "poll_ms", "", 1000);
    T_TRUE(drv_link_diff(k, &a, &b) == NULL);
    b = a;
    set(&b, "poll_ms", "", 2000);
    T_EQ_STR(drv_link_diff(k, &a, &b)->name, "poll_ms");
    drv_link_show(&b, k, drv_link_option("poll_ms"), shown, sizeof(shown));
    T_EQ_STR(shown, "2000");
    /* an option the kind does not take changes nothing it uses */
    b = a;
    set(&b, "serial", "01S00A", 0);
    T_TRUE(drv_link_diff(k, &a, &b) == NULL);
}
