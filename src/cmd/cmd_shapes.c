/*
 * cmd_shapes.c - `slimfarm shapes DIR`: write the generated test parts
 * (tee, arch, L-bracket, sphere on a stem, frame, torus) as binary STL, for
 * the demo and for trying the pipeline without any model files.
 */
#include <errno.h>
#include <stdio.h>
#include <sys/stat.h>

#include "../mesh/shapes.h"
#include "cmd.h"

static int
torus(struct mesh *m, struct sf_err *err)
{
    /* the peers' validation torus, standing upright (R 30, r 10) */
    int rc = shape_torus(m, 30, 10, 96, 48, err);
    if (rc == SF_OK) {
        mesh_transform(m, m3_axis_angle(v3(1, 0, 0), M_PI / 2), v3(0, 0, 0));
        mesh_place_on_bed(m, 0, 0);
    }
    return rc;
}

static const struct {
    const char *name;
    int (*make)(struct mesh *, struct sf_err *);
} parts[] = {
    { "tee", shape_tee },           { "arch", shape_arch },
    { "lbracket", shape_lbracket }, { "mushroom", shape_sphere_on_stem },
    { "frame", shape_frame },       { "torus", torus },
};

static int
run(int argc, char **argv)
{
    if (argc != 2 || argv[1][0] == '-') {
        fprintf(stderr, "usage: slimfarm shapes DIR\n");
        return 2;
    }
    if (mkdir(argv[1], 0755) != 0 && errno != EEXIST) {
        fprintf(stderr, "slimfarm shapes: cannot create '%s': %s\n", argv[1], strerror(errno));
        return 1;
    }
    for (size_t i = 0; i < sizeof(parts) / sizeof(parts[0]); i++) {
        struct mesh m;
        struct sf_err err;
        char path[4096];
        mesh_init(&m);
        snprintf(path, sizeof(path), "%s/%s.stl", argv[1], parts[i].name);
        if (parts[i].make(&m, &err) != SF_OK || mesh_save_stl(&m, path, &err) != SF_OK) {
            fprintf(stderr, "slimfarm shapes: %s: %s\n", parts[i].name, err.msg);
            mesh_release(&m);
            return 1;
        }
        printf("%s\n", path);
        mesh_release(&m);
    }
    return 0;
}

CMD_REGISTER(shapes, "shapes", "shapes DIR", "write the generated demo and test parts as STL", run)
