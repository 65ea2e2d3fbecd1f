/* vtexp-fw-host: the firmware's core on a POSIX host, behind a pseudo-terminal.
 *
 *   vtexp-fw-host ROWS COLS ACTUATOR DRIVE MAX_LEVEL MAX_MV MAX_CHZ MAX_US MAX_PULSES
 *                 MAX_PAYLOAD MIN_WD MAX_WD FIRMWARE DEVICE_ID [--trace FILE]
 *                 [--drop P] [--corrupt P] [--insert P] [--seed N]
 *
 * The same core as the microcontroller builds (and the same bytes on the wire), with
 * the host's monotonic clock and outputs that exist only as a record: fast to start
 * and to run, for tests that need the C firmware but not the chip (the chip is
 * vtexp-simavr's). Its pty is vtexp-simavr's too (firmware/pty/vt_pty.h): it prints
 * "port /dev/pts/N", serves until SIGTERM, SIGINT or "quit" on stdin, and takes "mute",
 * "unmute", "unplug", "replug", "faults D C I" and "flush".
 * The trace has a line per change of the outputs: {"t": us, "set": [[index, a, f, w],
 * ...]} (a is the level, or the amplitude in mV), and {"t": us, "off": 1} for all off.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vt_core.h"
#include "vt_hal.h"
#include "vt_profile.h"
#include "vt_pty.h"

static vt_config cfg;
static vt_setting outputs[VT_MAX_ACTUATORS], staged[VT_MAX_ACTUATORS];
static uint8_t changed[VT_MAX_ACTUATORS];
static FILE *trace;
static uint64_t t0_ns;
static vt_pty pty;

/* ------------------------------------------------------------------ the HAL */

uint64_t vt_hal_now_us(void) { return (vt_mono_ns() - t0_ns) / 1000; }

void vt_hal_tx(uint8_t byte) { vt_pty_send(&pty, byte); }

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
    vt_pty_init(&pty, "vtexp-fw-host");
    for (int i = 15; i < argc; i++) {
        if (!strcmp(argv[i], "--trace") && i + 1 < argc) {
            trace = fopen(argv[++i], "w");
            if (!trace) {
                perror(argv[i]);
                return 1;
            }
            setvbuf(trace, NULL, _IOLBF, 0);
        } else if (!vt_pty_option(&pty, argc, argv, &i)) {
            fprintf(stderr, "vtexp-fw-host: unknown argument %s\n", argv[i]);
            return 1;
        }
    }
    pty.trace = trace;
    vt_pty_catch_signals();
    t0_ns = vt_mono_ns();
    vt_init(&cfg);
    if (vt_pty_open(&pty) != 0)
        return 1;
    while (!vt_pty_stopping) {
        uint64_t due = vt_next_deadline_us();
        uint64_t now = vt_hal_now_us();
        uint64_t wait_us = 50000;
        if (due != VT_NEVER)
            wait_us = due <= now ? 0 : due - now;
        if (wait_us > 50000)
            wait_us = 50000;
        vt_pty_wait(&pty, wait_us * 1000);
        uint8_t b;
        while (vt_pty_recv(&pty, &b))
            vt_rx_byte(b);
        vt_poll();
        vt_pty_flush(&pty);
    }
    const vt_counters *c = vt_get_counters();
    fprintf(stderr, "vtexp-fw-host: stopped: %lu frames received, %lu bad, %lu answered from "
                    "the cache, %u watchdog trips\n", (unsigned long)c->rx_frames,
            (unsigned long)c->rx_bad, (unsigned long)c->duplicates, c->watchdog_trips);
    if (trace)
        fclose(trace);
    vt_pty_close(&pty);
    return 0;
}
