/*
 * drv_link.c - a printer's link options (drv_link.h): lookups over the
 * kinds' option tables, the values a section gave, and the struct
 * drv_config they make.  Thread: any.
 */
#include "drv_link.h"

#include <stdio.h>
#include <string.h>

const struct drv_option *
drv_kind_option(const struct drv_kind *k, size_t i)
{
    if (!k)
        return NULL;
    for (size_t t = 0; t < sizeof(k->options) / sizeof(k->options[0]) && k->options[t]; t++)
        for (const struct drv_option *o = k->options[t]; o->name; o++)
            if (i-- == 0)
                return o;
    return NULL;
}

bool
drv_kind_takes(const struct drv_kind *k, const struct drv_option *o)
{
    const struct drv_option *ko;
    for (size_t i = 0; (ko = drv_kind_option(k, i)); i++)
        if (ko == o)
            return true;
    return false;
}

/* Has an earlier kind than kind number ki listed o (a shared table)? */
static bool
listed_before(size_t ki, const struct drv_option *o)
{
    for (size_t j = 0; j < ki; j++)
        if (drv_kind_takes(drv_kind_at(j), o))
            return true;
    return false;
}

const struct drv_option *
drv_link_option_at(size_t i)
{
    const struct drv_kind *k;
    for (size_t ki = 0; (k = drv_kind_at(ki)); ki++) {
        const struct drv_option *o;
        for (size_t oi = 0; (o = drv_kind_option(k, oi)); oi++)
            if (!listed_before(ki, o) && i-- == 0)
                return o;
    }
    return NULL;
}

const struct drv_option *
drv_link_option(const char *name)
{
    const struct drv_option *o;
    for (size_t i = 0; (o = drv_link_option_at(i)); i++)
        if (strcmp(o->name, name) == 0)
            return o;
    return NULL;
}

void
drv_link_init(struct drv_link *l)
{
    memset(l, 0, sizeof(*l));
}

static bool
is_text(const struct drv_option *o)
{
    return o->type != DRV_OPT_INT && o->type != DRV_OPT_BOOL;
}

int
drv_link_set(struct drv_link *l, const struct drv_option *o, const char *text, int num, int line,
             struct sf_err *err)
{
    if (drv_link_get(l, o))
        return sf_err_set(err, SF_EINVAL, "option '%s' is given twice", o->name);
    if (l->n == SF_LINK_OPTS_MAX)
        return sf_err_set(err, SF_EINVAL, "more than %d link options", SF_LINK_OPTS_MAX);
    struct drv_link_val *v = &l->v[l->n];
    *v = (struct drv_link_val){ .opt = o, .line = line, .num = num };
    if (is_text(o)) {
        const char *pre = o->prefix && text[0] ? o->prefix : "";
        size_t need = strlen(pre) + strlen(text) + 1;
        if (need > sizeof(l->text) - l->used)
            return sf_err_set(err, SF_EINVAL, "option '%s': no room for its value", o->name);
        v->at = l->used;
        snprintf(l->text + l->used, need, "%s%s", pre, text);
        l->used += need;
    }
    l->n++;
    return SF_OK;
}

const struct drv_link_val *
drv_link_get(const struct drv_link *l, const struct drv_option *o)
{
    for (size_t i = 0; i < l->n; i++)
        if (l->v[i].opt == o)
            return &l->v[i];
    return NULL;
}

const char *
drv_link_text(const struct drv_link *l, const char *name)
{
    const struct drv_option *o = drv_link_option(name);
    const struct drv_link_val *v = o && is_text(o) ? drv_link_get(l, o) : NULL;
    return v ? l->text + v->at : "";
}

void
drv_link_config(const struct drv_link *l, const struct drv_kind *k, struct drv_config *cfg)
{
    char *base = (char *)cfg;
    const struct drv_option *o;
    for (size_t i = 0; (o = drv_kind_option(k, i)); i++)
        if (o->type == DRV_OPT_INT)
            *(int *)(base + o->off) = o->def;
        else if (o->type == DRV_OPT_BOOL)
            *(bool *)(base + o->off) = o->def != 0;
        else
            *(const char **)(base + o->off) = "";
    for (size_t i = 0; i < l->n; i++) {
        const struct drv_link_val *v = &l->v[i];
        if (!drv_kind_takes(k, v->opt))
            continue;
        void *field = base + v->opt->off;
        if (v->opt->type == DRV_OPT_INT)
            *(int *)field = v->num;
        else if (v->opt->type == DRV_OPT_BOOL)
            *(bool *)field = v->num != 0;
        else if (!(v->opt->flags & DRV_OPT_FALLBACK) || !**(const char **)field)
            *(const char **)field = l->text + v->at;
    }
}

/* Do a and b hold the same value in o's field? */
static bool
same_field(const struct drv_option *o, const struct drv_config *a, const struct drv_config *b)
{
    const char *pa = (const char *)a + o->off, *pb = (const char *)b + o->off;
    if (o->type == DRV_OPT_INT)
        return *(const int *)pa == *(const int *)pb;
    if (o->type == DRV_OPT_BOOL)
        return *(const bool *)pa == *(const bool *)pb;
    return strcmp(*(const char *const *)pa, *(const char *const *)pb) == 0;
}

const struct drv_option *
drv_link_diff(const struct drv_kind *k, const struct drv_link *a, const struct drv_link *b)
{
    struct drv_config ca = { 0 }, cb = { 0 };
    drv_link_config(a, k, &ca);
    drv_link_config(b, k, &cb);
    const struct drv_option *o;
    for (size_t i = 0; (o = drv_kind_option(k, i)); i++)
        if (!(o->flags & DRV_OPT_LIVE) && !same_field(o, &ca, &cb))
            return o;
    return NULL;
}

void
drv_link_show(const struct drv_link *l, const struct drv_kind *k, const struct drv_option *o,
              char *out, size_t n)
{
    struct drv_config cfg = { 0 };
    drv_link_config(l, k, &cfg);
    const char *p = (const char *)&cfg + o->off;
    if (o->flags & DRV_OPT_SECRET)
        snprintf(out, n, "(secret)");
    else if (o->type == DRV_OPT_INT)
        snprintf(out, n, "%d", *(const int *)p);
    else if (o->type == DRV_OPT_BOOL)
        snprintf(out, n, "%s", *(const bool *)p ? "true" : "false");
    else
        snprintf(out, n, "%s", *(const char *const *)p ? *(const char *const *)p : "");
}
