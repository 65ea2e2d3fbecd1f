/* The device's end of a pseudo-terminal, for the programs that stand in for a board on
 * this computer: vtexp-fw-host (the core, ports/host) and vtexp-simavr (the chip in
 * simavr, sim/). vtexp talks to either as to a board, through serial:/dev/pts/N.
 *
 * What both do with it, and so what lives here:
 *  - open it raw and non-blocking, and print "port /dev/pts/N" on stdout for vtexp;
 *  - damage the line when asked (each byte, both ways: dropped, altered, or followed
 *    by a random byte, with the given probabilities; seeded, so a run can be repeated);
 *  - queue the bytes each way: the host's until the device takes them
 *    (vt_pty_recv), the device's until the host reads them (vt_pty_flush);
 *  - take commands on stdin, one a line, each answered "ok LINE" once done:
 *    "mute", "unmute" (no bytes either way), "unplug" (the pty closes), "replug" (a new
 *    one, printed as "port ..."), "faults D C I" (the probabilities), "flush" (the
 *    trace, to read it while running), "quit", and the program's own (vt_pty.command);
 *  - stop cleanly on SIGTERM or SIGINT (vt_pty_stopping).
 *
 * Both run one loop: vt_pty_wait() (until a byte, a command, or the time given), then
 * the device takes the host's bytes, runs, and vt_pty_flush() writes what it sent.
 */
#ifndef VT_PTY_H
#define VT_PTY_H

#include <signal.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#define VT_PTY_RING 0x10000                 /* bytes queued each way */

typedef struct vt_pty {
    const char *program;                    /* for error messages */
    int master, slave;
    int muted, unplugged;
    double p_drop, p_corrupt, p_insert;     /* per byte, both directions */
    uint64_t rng;
    FILE *trace;                            /* the program's trace, flushed by "flush" */
    /* The program's own commands: nonzero if line was one (it is then answered "ok"). */
    int (*command)(const char *line);
    /* counts: bytes the host wrote (before faults), the device sent, faults made */
    uint64_t n_rx, n_tx, n_dropped, n_corrupted, n_inserted;
    uint8_t rx[VT_PTY_RING], tx[VT_PTY_RING];   /* host -> device, device -> host */
    uint32_t rx_head, rx_tail, tx_head, tx_tail;
    int stdin_open;
    char line[256];                         /* a command being read */
    size_t line_n;
} vt_pty;

/* Set by SIGTERM, SIGINT (vt_pty_catch_signals) and "quit": the program ends its loop. */
extern volatile sig_atomic_t vt_pty_stopping;

/* Not open yet, no faults, stdin open for commands. */
void vt_pty_init(vt_pty *p, const char *program);
/* --drop P, --corrupt P, --insert P, --seed N at argv[*i]: nonzero if it was one of
 * them (*i is then on its value). */
int vt_pty_option(vt_pty *p, int argc, char **argv, int *i);
void vt_pty_catch_signals(void);

/* Open a pty and print "port NAME"; -1 (and a message on stderr) if none. */
int vt_pty_open(vt_pty *p);
/* Close it; whatever was queued either way is dropped (a cable pulled). */
void vt_pty_close(vt_pty *p);

/* A byte from the device to the host: queued, with faults; nothing while muted,
 * unplugged or closed (a UART sends into nothing). */
void vt_pty_send(vt_pty *p, uint8_t byte);
/* The next byte from the host for the device: 1 and *byte, or 0 if none is queued. */
static inline int vt_pty_recv(vt_pty *p, uint8_t *byte)
{
    if (p->rx_tail == p->rx_head)
        return 0;
    *byte = p->rx[p->rx_tail++ & (VT_PTY_RING - 1)];
    return 1;
}
/* Wait up to wait_ns (< 1 s) for a command or the host's bytes, and take what came:
 * commands are executed, the host's bytes queued (with faults) for vt_pty_recv. */
void vt_pty_wait(vt_pty *p, uint64_t wait_ns);
/* Write the device's queued bytes to the pty, as many as it takes now. */
void vt_pty_flush(vt_pty *p);

/* The monotonic clock, ns. */
uint64_t vt_mono_ns(void);

#endif
