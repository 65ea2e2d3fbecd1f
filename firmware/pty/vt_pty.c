/* The device's end of a pseudo-terminal (see vt_pty.h). */
#define _GNU_SOURCE
#include "vt_pty.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

volatile sig_atomic_t vt_pty_stopping;

#define RING_MASK (VT_PTY_RING - 1)

void vt_pty_init(vt_pty *p, const char *program)
{
    memset(p, 0, sizeof *p);
    p->program = program;
    p->master = p->slave = -1;
    p->rng = 0x9E3779B97F4A7C15ULL;
    p->stdin_open = 1;
}

int vt_pty_option(vt_pty *p, int argc, char **argv, int *i)
{
    const char *a = argv[*i];
    if (*i + 1 >= argc)
        return 0;
    if (!strcmp(a, "--drop"))
        p->p_drop = atof(argv[++*i]);
    else if (!strcmp(a, "--corrupt"))
        p->p_corrupt = atof(argv[++*i]);
    else if (!strcmp(a, "--insert"))
        p->p_insert = atof(argv[++*i]);
    else if (!strcmp(a, "--seed"))
        p->rng ^= strtoull(argv[++*i], NULL, 0) * 0x2545F4914F6CDD1DULL + 1;
    else
        return 0;
    return 1;
}

static void on_signal(int s)
{
    (void)s;
    vt_pty_stopping = 1;
}

void vt_pty_catch_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);                 /* a host gone: write fails, we go on */
}

uint64_t vt_mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ULL + (uint64_t)ts.tv_nsec;
}

/* ---------------------------------------------------------------- line faults */

static double uniform(vt_pty *p)
{
    p->rng ^= p->rng << 13;
    p->rng ^= p->rng >> 7;
    p->rng ^= p->rng << 17;
    return (double)(p->rng >> 11) / (double)(1ULL << 53);
}

/* A byte on the line, with faults: how many bytes (0-2) to pass on in out[]. */
static int mangle(vt_pty *p, uint8_t b, uint8_t out[2])
{
    if (p->p_drop > 0 && uniform(p) < p->p_drop) {
        p->n_dropped++;
        return 0;
    }
    if (p->p_corrupt > 0 && uniform(p) < p->p_corrupt) {
        b ^= (uint8_t)(1 + (uint8_t)(uniform(p) * 255));
        p->n_corrupted++;
    }
    out[0] = b;
    if (p->p_insert > 0 && uniform(p) < p->p_insert) {
        out[1] = (uint8_t)(uniform(p) * 256);
        p->n_inserted++;
        return 2;
    }
    return 1;
}

/* ---------------------------------------------------------------- the pty */

int vt_pty_open(vt_pty *p)
{
    char name[256];
    if (openpty(&p->master, &p->slave, name, NULL, NULL) < 0) {
        fprintf(stderr, "%s: openpty: %s\n", p->program, strerror(errno));
        p->master = p->slave = -1;
        return -1;
    }
    struct termios t;
    tcgetattr(p->slave, &t);
    cfmakeraw(&t);
    tcsetattr(p->slave, TCSANOW, &t);
    fcntl(p->master, F_SETFL, O_NONBLOCK);
    printf("port %s\n", name);
    fflush(stdout);
    return 0;
}

void vt_pty_close(vt_pty *p)
{
    if (p->master >= 0)
        close(p->master);
    if (p->slave >= 0)
        close(p->slave);
    p->master = p->slave = -1;
    p->rx_head = p->rx_tail = p->tx_head = p->tx_tail = 0;
}

void vt_pty_send(vt_pty *p, uint8_t byte)
{
    uint8_t m[2];
    p->n_tx++;
    if (p->muted || p->unplugged || p->master < 0)
        return;
    int n = mangle(p, byte, m);
    for (int i = 0; i < n; i++)
        p->tx[p->tx_head++ & RING_MASK] = m[i];
}

void vt_pty_flush(vt_pty *p)
{
    while (p->tx_tail != p->tx_head && p->master >= 0) {
        uint32_t n = p->tx_head - p->tx_tail, at = p->tx_tail & RING_MASK;
        if (at + n > VT_PTY_RING)
            n = VT_PTY_RING - at;
        ssize_t w = write(p->master, &p->tx[at], n);
        if (w <= 0)
            return;                           /* the host is not reading: keep it for later */
        p->tx_tail += (uint32_t)w;
    }
}

static void read_host(vt_pty *p)
{
    uint8_t buf[4096];
    ssize_t n = read(p->master, buf, sizeof buf);
    if (n <= 0 || p->muted)
        return;
    for (ssize_t i = 0; i < n; i++) {
        uint8_t m[2];
        int k = mangle(p, buf[i], m);
        for (int j = 0; j < k; j++)
            p->rx[p->rx_head++ & RING_MASK] = m[j];
    }
    p->n_rx += (uint64_t)n;
}

/* ---------------------------------------------------------------- commands */

static void command(vt_pty *p, const char *line)
{
    if (!strcmp(line, "mute")) {
        p->muted = 1;
    } else if (!strcmp(line, "unmute")) {
        p->muted = 0;
    } else if (!strcmp(line, "unplug")) {
        p->unplugged = 1;
        vt_pty_close(p);
    } else if (!strcmp(line, "replug")) {
        vt_pty_close(p);
        p->unplugged = 0;
        vt_pty_open(p);
    } else if (!strncmp(line, "faults ", 7)) {
        sscanf(line + 7, "%lf %lf %lf", &p->p_drop, &p->p_corrupt, &p->p_insert);
    } else if (!strcmp(line, "flush")) {
        if (p->trace)
            fflush(p->trace);
    } else if (!strcmp(line, "quit")) {
        vt_pty_stopping = 1;
    } else if (p->command) {
        p->command(line);
    }
    printf("ok %s\n", line);
    fflush(stdout);
}

static void read_commands(vt_pty *p)
{
    ssize_t r = read(0, p->line + p->line_n, sizeof p->line - 1 - p->line_n);
    if (r <= 0) {
        p->stdin_open = 0;                    /* no more commands; run on */
        return;
    }
    p->line_n += (size_t)r;
    p->line[p->line_n] = 0;
    char *nl;
    while ((nl = strchr(p->line, '\n'))) {
        *nl = 0;
        command(p, p->line);
        memmove(p->line, nl + 1, strlen(nl + 1) + 1);
        p->line_n = strlen(p->line);
    }
    if (p->line_n == sizeof p->line - 1)
        p->line_n = 0;                        /* a line too long for a command: dropped */
}

void vt_pty_wait(vt_pty *p, uint64_t wait_ns)
{
    struct pollfd pf[2] = {{p->stdin_open ? 0 : -1, POLLIN, 0}, {p->master, POLLIN, 0}};
    if (p->tx_tail != p->tx_head)
        pf[1].events |= POLLOUT;
    struct timespec wait = {(time_t)(wait_ns / 1000000000ULL), (long)(wait_ns % 1000000000ULL)};
    if (ppoll(pf, p->master >= 0 ? 2 : 1, &wait, NULL) <= 0)
        return;
    if (pf[0].revents & POLLIN)
        read_commands(p);
    if (p->master >= 0 && (pf[1].revents & POLLIN))
        read_host(p);
}
