/*
 * cmd_ports.c - `slimfarm ports`: list serial ports with their USB ids and
 * descriptions, to find which /dev/tty* is which printer.
 *
 * Thread: main thread.  Uses transport_list_ports() (libserialport).
 */
#include <stdio.h>
#include <stdlib.h>

#include "../../drivers/marlin/transport.h"
#include "cmd.h"

static int
run_ports(int argc, char **argv)
{
    (void)argv;
    if (argc > 1) {
        fprintf(stderr, "usage: slimfarm ports\n");
        return 2;
    }
    struct transport_port *ports;
    size_t n;
    struct sf_err err;
    if (transport_list_ports(&ports, &n, &err) < 0) {
        fprintf(stderr, "slimfarm ports: %s\n", err.msg);
        return 1;
    }
    if (n == 0)
        printf("no serial ports found\n");
    for (size_t i = 0; i < n; i++) {
        const struct transport_port *p = &ports[i];
        if (p->vid >= 0)
            printf("%-20s %04x:%04x %-32s %s\n", p->name, (unsigned)p->vid, (unsigned)p->pid,
                   p->description, p->serial);
        else
            printf("%-20s %-9s %s\n", p->name, "-", p->description);
    }
    free(ports);
    return 0;
}

CMD_REGISTER(ports, "ports", "ports", "list serial ports with USB VID:PID and description",
             run_ports)
