/* vtexp-fw-host: the firmware's core on a POSIX host, behind a pseudo-terminal.
 *
 *   vtexp-fw-host ROWS COLS ACTUATOR DRIVE MAX_LEVEL MAX_MV MAX_CHZ MAX_US MAX_PULSES
 *                 MAX_PAYLOAD MIN_WD MAX_WD FIRMWARE DEVICE_ID [--trace FILE]
 *                 [--drop P] [--corrupt P] [--insert P] [--seed N]
 *
 * The same core as the microcontroller builds (and the same bytes on the wire), with
 * the host's monotonic clock and outputs that exist only as a record: fast to start
 * and to run, for tests that need the C firmware but not the chip (the chip is
 * vtexp-simavr's). It prints "port /dev/pts/N", serves until SIGTERM, SIGINT or
 * "quit" on stdin, and takes "mute", "unmute", "unplug", "replug" like vtexp-simavr.
 * The trace has a line per change of the outputs: {"t": us, "set": [[index, a, f, w],
 * ...]} (a is the level, or the amplitude in mV), and {"t": us, "off": 1} for all off.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "vt_core.h"
#include "vt_hal.h"
#include "vt_profile.h"

static vt_config cfg;
static vt_setting outputs[VT_MAX_ACTUATORS], staged[VT_MAX_ACTUATORS];
static uint8_t changed[VT_MAX_ACTUATORS];
static FILE *trace;
static uint64_t t0_ns;
static int master = -1, slave = -1, muted, unplugged;
static volatile sig_atomic_t stopping;
static double p_drop, p_corrupt, p_insert;
static uint64_t rng = 0x9E3779B97F4A7C15ULL;
static uint8_t txq[1 << 16];
static uint32_t tx_head, tx_tail;

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ULL + (uint64_t)ts.tv_nsec;
}

static double uniform(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (double)(rng >> 11) / (double)(1ULL << 53);
}

/* A byte on the line, with faults: 0-2 bytes passed on. */
static int mangle(uint8_t b, uint8_t out[2])
{
    if (p_drop > 0 && uniform() < p_drop)
        return 0;
    if (p_corrupt > 0 && uniform() < p_corrupt)
        b ^= (uint8_t)(1 + (uint8_t)(uniform() * 255));
    out[0] = b;
    if (p_insert > 0 && uniform() < p_insert) {
        out[1] = (uint8_t)(uniform() * 256);
        return 2;
    }
    return 1;
}

/* ------------------------------------------------------------------ the HAL */

uint64_t vt_hal_now_us(void) { return (mono_ns() - t0_ns) / 1000; }

void vt_hal_tx(uint8_t byte)
{
    uint8_t m[2];
    if (muted || unplugged || master < 0)
        return;
    int n = mangle(byte, m);
    for (int i = 0; i < n; i++)
        txq[tx_head++ & 0xFFFF] = m[i];
}

void vt_hal_stage_begin(void)
{
    memcpy(staged, outputs, sizeof outputs);
    memset(changed, 0, sizeof changed);
}

void vt_hal_stage(uint16_t index, const vt_setting *s)
{
    if (index < VT_MAX_ACTUATORS) {
        staged[index] = *s;
        changed[index] = 1;
    }
}

static uint64_t commit(void)
{
    uint64_t t = vt_hal_now_us();
    char buf[64];
    int any = 0;
    for (uint16_t i = 0; i < VT_MAX_ACTUATORS; i++) {
        if (!changed[i] || !memcmp(&outputs[i], &staged[i], sizeof staged[i]))
            continue;
        outputs[i] = staged[i];
        if (trace) {
            if (!any)
                fprintf(trace, "{\"t\":%llu,\"set\":[", (unsigned long long)t);
            snprintf(buf, sizeof buf, "%s[%u,%u,%u,%u]", any ? "," : "", i, staged[i].a,
                     staged[i].f, staged[i].w);
            fputs(buf, trace);
        }
        any = 1;
    }
    if (trace && any)
        fputs("]}\n", trace);
    memset(changed, 0, sizeof changed);
    return t;
}

uint64_t vt_hal_commit_now(void) { return commit(); }

uint64_t vt_hal_commit_time(uint64_t t_us)
{
    uint64_t now = vt_hal_now_us();
    return t_us > now ? t_us : now;
}

static uint64_t last_commit;

void vt_hal_commit_at(uint64_t t_us, uint8_t onsets)
{
    (void)t_us;
    (void)onsets;
    last_commit = commit();                   /* the core commits only what is due */
}

uint8_t vt_hal_committed(uint64_t *t_us)
{
    *t_us = last_commit;
    return 1;
}

void vt_hal_all_off(void)
{
    memset(outputs, 0, sizeof outputs);
    memset(staged, 0, sizeof staged);
    memset(changed, 0, sizeof changed);
    if (trace)
        fprintf(trace, "{\"t\":%llu,\"off\":1}\n", (unsigned long long)vt_hal_now_us());
}

uint64_t vt_hal_align_start(uint64_t t_us) { return t_us; }

void vt_hal_set_deadline(uint64_t t_us) { (void)t_us; }

/* ------------------------------------------------------------------ the pty */

static int open_pty(void)
{
    char name[256];
    if (openpty(&master, &slave, name, NULL, NULL) < 0) {
        perror("vtexp-fw-host: openpty");
        return -1;
    }
    struct termios t;
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(master, F_SETFL, O_NONBLOCK);
    printf("port %s\n", name);
    fflush(stdout);
    return 0;
}

static void close_pty(void)
{
    if (master >= 0)
        close(master);
    if (slave >= 0)
        close(slave);
    master = slave = -1;
    tx_head = tx_tail = 0;
}

static void command(const char *line)
{
    if (!strcmp(line, "mute"))
        muted = 1;
    else if (!strcmp(line, "unmute"))
        muted = 0;
    else if (!strcmp(line, "unplug")) {
        unplugged = 1;
        close_pty();
    } else if (!strcmp(line, "replug")) {
        close_pty();
        unplugged = 0;
        open_pty();
    } else if (!strcmp(line, "flush")) {
        if (trace)
            fflush(trace);
    } else if (!strcmp(line, "quit"))
        stopping = 1;
    printf("ok %s\n", line);
    fflush(stdout);
}

static void on_signal(int s)
{
    (void)s;
    stopping = 1;
}

int main(int argc, char **argv)
{
    static char fw[256], id[256];
    if (argc < 15) {
        fprintf(stderr, "usage: vtexp-fw-host ROWS COLS ACTUATOR DRIVE MAX_LEVEL MAX_MV MAX_CHZ "
                        "MAX_US MAX_PULSES MAX_PAYLOAD MIN_WD MAX_WD FIRMWARE DEVICE_ID "
                        "[--trace FILE] [--drop P] [--corrupt P] [--insert P] [--seed N]\n");
        return 1;
    }
    long v[12];
    for (int i = 0; i < 12; i++)
        v[i] = strtol(argv[1 + i], NULL, 10);
    snprintf(fw, sizeof fw, "%s", argv[13]);
    snprintf(id, sizeof id, "%s", argv[14]);
    cfg = (vt_config){(uint16_t)v[0], (uint16_t)v[1], (uint8_t)v[2], (uint8_t)v[3],
                      (uint8_t)v[4], (uint16_t)v[5], (uint16_t)v[6], (uint16_t)v[7],
                      (uint16_t)v[8], (uint16_t)v[9], (uint16_t)v[10], (uint16_t)v[11], fw, id};
    if ((long)cfg.rows * cfg.cols > VT_MAX_ACTUATORS || cfg.max_pulses > VT_MAX_PULSES
        || cfg.max_payload > VT_MAX_PAYLOAD) {
        fprintf(stderr, "vtexp-fw-host: the configuration exceeds what this build holds "
                        "(%d actuators, %d pulses, %d-byte payloads)\n",
                VT_MAX_ACTUATORS, VT_MAX_PULSES, VT_MAX_PAYLOAD);
        return 1;
    }
    for (int i = 15; i < argc; i++) {
        if (!strcmp(argv[i], "--trace") && i + 1 < argc) {
            trace = fopen(argv[++i], "w");
            if (!trace) {
                perror(argv[i]);
                return 1;
            }
            setvbuf(trace, NULL, _IOLBF, 0);
        } else if (!strcmp(argv[i], "--drop") && i + 1 < argc)
            p_drop = atof(argv[++i]);
        else if (!strcmp(argv[i], "--corrupt") && i + 1 < argc)
            p_corrupt = atof(argv[++i]);
        else if (!strcmp(argv[i], "--insert") && i + 1 < argc)
            p_insert = atof(argv[++i]);
        else if (!strcmp(argv[i], "--seed") && i + 1 < argc)
            rng ^= strtoull(argv[++i], NULL, 0) * 0x2545F4914F6CDD1DULL + 1;
        else {
            fprintf(stderr, "vtexp-fw-host: unknown argument %s\n", argv[i]);
            return 1;
        }
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    t0_ns = mono_ns();
    vt_init(&cfg);
    if (open_pty() != 0)
        return 1;
    char line[256];
    size_t line_n = 0;
    int stdin_open = 1;
    while (!stopping) {
        uint64_t due = vt_next_deadline_us();
        uint64_t now = vt_hal_now_us();
        uint64_t wait_us = 50000;
        if (due != VT_NEVER)
            wait_us = due <= now ? 0 : due - now;
        if (wait_us > 50000)
            wait_us = 50000;
        struct timespec wait = {0, (long)wait_us * 1000};
        struct pollfd pf[2] = {{stdin_open ? 0 : -1, POLLIN, 0}, {master, POLLIN, 0}};
        if (master >= 0 && tx_tail != tx_head)
            pf[1].events |= POLLOUT;
        int r = ppoll(pf, master >= 0 ? 2 : 1, &wait, NULL);
        if (r > 0 && (pf[0].revents & POLLIN)) {
            ssize_t n = read(0, line + line_n, sizeof line - 1 - line_n);
            if (n <= 0) {
                stdin_open = 0;
            } else {
                line_n += (size_t)n;
                line[line_n] = 0;
                char *nl;
                while ((nl = strchr(line, '\n'))) {
                    *nl = 0;
                    command(line);
                    memmove(line, nl + 1, strlen(nl + 1) + 1);
                    line_n = strlen(line);
                }
                if (line_n == sizeof line - 1)
                    line_n = 0;
            }
        }
        if (r > 0 && master >= 0 && (pf[1].revents & POLLIN)) {
            uint8_t buf[4096];
            ssize_t n = read(master, buf, sizeof buf);
            for (ssize_t i = 0; i < n && !muted; i++) {
                uint8_t m[2];
                int k = mangle(buf[i], m);
                for (int j = 0; j < k; j++)
                    vt_rx_byte(m[j]);
            }
        }
        vt_poll();
        while (master >= 0 && tx_tail != tx_head) {
            uint32_t n = tx_head - tx_tail, at = tx_tail & 0xFFFF;
            if (at + n > sizeof txq)
                n = (uint32_t)sizeof txq - at;
            ssize_t w = write(master, &txq[at], n);
            if (w <= 0)
                break;
            tx_tail += (uint32_t)w;
        }
    }
    const vt_counters *c = vt_get_counters();
    fprintf(stderr, "vtexp-fw-host: stopped: %lu frames received, %lu bad, %lu answered from "
                    "the cache, %u watchdog trips\n", (unsigned long)c->rx_frames,
            (unsigned long)c->rx_bad, (unsigned long)c->duplicates, c->watchdog_trips);
    if (trace)
        fclose(trace);
    close_pty();
    return 0;
}
