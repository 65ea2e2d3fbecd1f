/* The vector runner (see vt_runner.h): the core with a fake clock and recorded
 * outputs behind a line protocol. It is also the HAL of the runner builds. */
#include <stdint.h>
#include <string.h>

#include "vt_cobs.h"
#include "vt_core.h"
#include "vt_crc32.h"
#include "vt_hal.h"
#include "vt_profile.h"
#include "vt_runner.h"

#ifndef VT_RUNNER_LINE
#define VT_RUNNER_LINE 4200
#endif
#ifndef VT_RUNNER_OUTPUTS
#define VT_RUNNER_OUTPUTS 1
#endif

static uint64_t now_us;
static char line[VT_RUNNER_LINE];
static uint8_t bytes[VT_RUNNER_LINE / 2];
static vt_config cfg;
static char fw_name[64], dev_id[64];

#if VT_RUNNER_OUTPUTS
static vt_setting outputs[VT_MAX_ACTUATORS], staged[VT_MAX_ACTUATORS];
#endif

/* ------------------------------------------------------------------ the HAL: a fake clock */

uint64_t vt_hal_now_us(void) { return now_us; }

static void put_hex(uint8_t b)
{
    static const char digits[] = "0123456789abcdef";
    vt_runner_putc(digits[b >> 4]);
    vt_runner_putc(digits[b & 15]);
}

void vt_hal_tx(uint8_t byte) { put_hex(byte); }

void vt_hal_stage_begin(void)
{
#if VT_RUNNER_OUTPUTS
    memcpy(staged, outputs, sizeof outputs);
#endif
}

void vt_hal_stage(uint16_t index, const vt_setting *s)
{
#if VT_RUNNER_OUTPUTS
    if (index < VT_MAX_ACTUATORS)
        staged[index] = *s;
#else
    (void)index;
    (void)s;
#endif
}

static void apply(void)
{
#if VT_RUNNER_OUTPUTS
    memcpy(outputs, staged, sizeof outputs);
#endif
}

uint64_t vt_hal_commit_now(void)
{
    apply();
    return now_us;
}

uint64_t vt_hal_commit_time(uint64_t t_us) { return t_us > now_us ? t_us : now_us; }

void vt_hal_commit_at(uint64_t t_us, uint8_t onsets)
{
    (void)t_us;
    (void)onsets;
    apply();                              /* the core commits only what is due */
}

uint8_t vt_hal_committed(uint64_t *t_us)
{
    *t_us = now_us;
    return 1;
}

void vt_hal_all_off(void)
{
#if VT_RUNNER_OUTPUTS
    memset(outputs, 0, sizeof outputs);
    memset(staged, 0, sizeof staged);
#endif
}

uint64_t vt_hal_align_start(uint64_t t_us) { return t_us; }

void vt_hal_set_deadline(uint64_t t_us) { (void)t_us; }

/* ------------------------------------------------------------------ parsing */

static void puts_(const char *s)
{
    while (*s)
        vt_runner_putc(*s++);
}

#if VT_RUNNER_OUTPUTS
static void put_dec(uint32_t v)
{
    char buf[11];
    int n = 0;
    do {
        buf[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    while (n)
        vt_runner_putc(buf[--n]);
}
#endif

static char *next_token(char **cursor)
{
    char *s = *cursor;
    while (*s == ' ')
        s++;
    if (!*s)
        return 0;
    char *start = s;
    while (*s && *s != ' ')
        s++;
    if (*s)
        *s++ = 0;
    *cursor = s;
    return start;
}

static uint64_t dec_u64(const char *s)
{
    uint64_t v = 0;
    while (s && *s >= '0' && *s <= '9')
        v = v * 10 + (uint64_t)(*s++ - '0');
    return v;
}

static int hexval(char c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'a' && c <= 'f')
        return c - 'a' + 10;
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    return -1;
}

/* Hex to bytes; "-" or nothing is no bytes. Returns the count, or -1 if malformed. */
static int32_t unhex(const char *s, uint8_t *out)
{
    int32_t n = 0;
    if (!s || (s[0] == '-' && s[1] == 0))
        return 0;
    while (s[0] && s[1]) {
        int hi = hexval(s[0]), lo = hexval(s[1]);
        if (hi < 0 || lo < 0)
            return -1;
        out[n++] = (uint8_t)(hi << 4 | lo);
        s += 2;
    }
    return s[0] ? -1 : n;
}

static void text_of(const char *hex, char *out, uint16_t cap)
{
    int32_t n = unhex(hex, (uint8_t *)out);
    if (n < 0 || (uint16_t)n >= cap)
        n = 0;
    out[n] = 0;
}

/* ------------------------------------------------------------------ commands */

static void cmd_config(char *args)
{
    uint32_t v[12];
    for (uint8_t i = 0; i < 12; i++)
        v[i] = (uint32_t)dec_u64(next_token(&args));
    /* Field by field, though the lines look alike: each says which number is which
     * field, and the fields are of two widths; a table of offsets and sizes would be
     * longer and say less. */
    cfg.rows = (uint16_t)v[0];
    cfg.cols = (uint16_t)v[1];
    cfg.actuator = (uint8_t)v[2];
    cfg.drive = (uint8_t)v[3];
    cfg.max_level = (uint8_t)v[4];
    cfg.max_amplitude_mv = (uint16_t)v[5];
    cfg.max_frequency_chz = (uint16_t)v[6];
    cfg.max_width_us = (uint16_t)v[7];
    cfg.max_pulses = (uint16_t)v[8];
    cfg.max_payload = (uint16_t)v[9];
    cfg.min_watchdog_ms = (uint16_t)v[10];
    cfg.max_watchdog_ms = (uint16_t)v[11];
    text_of(next_token(&args), fw_name, sizeof fw_name);
    text_of(next_token(&args), dev_id, sizeof dev_id);
    cfg.firmware = fw_name;
    cfg.device_id = dev_id;
    now_us = 0;
    vt_init(&cfg);
    puts_("ok");
}

static void cmd_at(char *args, uint8_t with_bytes)
{
    now_us = dec_u64(next_token(&args));
    int32_t n = with_bytes ? unhex(next_token(&args), bytes) : 0;
    if (n < 0) {
        puts_("! bad hex");
        return;
    }
    puts_("= ");
    for (int32_t i = 0; i < n; i++)
        vt_rx_byte(bytes[i]);
    vt_poll();                            /* what is due after the bytes: as the emulator */
}

static void cmd_crc(char *args)
{
    int32_t n = unhex(next_token(&args), bytes);
    uint32_t c = vt_crc32(bytes, n > 0 ? (size_t)n : 0);
    puts_("= ");
    for (int8_t i = 3; i >= 0; i--)
        put_hex((uint8_t)(c >> (8 * i)));
}

static void cmd_cobs(char *args)
{
    int32_t n = unhex(next_token(&args), bytes);
    puts_("= ");
    vt_cobs_enc_begin();
    for (int32_t i = 0; i < n; i++)
        vt_cobs_enc_byte(bytes[i]);
    vt_cobs_enc_end();
}

static void cmd_uncobs(char *args)
{
    static uint8_t out[VT_RUNNER_LINE / 2];
    int32_t n = unhex(next_token(&args), bytes);
    vt_cobs_dec d;
    vt_cobs_dec_init(&d, out, sizeof out);
    for (int32_t i = 0; i < n; i++)
        vt_cobs_dec_byte(&d, bytes[i]);
    int16_t r = vt_cobs_dec_end(&d);
    if (r == VT_COBS_BAD) {
        puts_("! bad");
    } else if (r == VT_COBS_TOO_LONG) {
        puts_("! too_long");
    } else {
        puts_("= ");
        for (int16_t i = 0; i < r; i++)
            put_hex(out[i]);
    }
}

static void cmd_frame(char *args)
{
    uint8_t type = (uint8_t)dec_u64(next_token(&args));
    uint8_t seq = (uint8_t)dec_u64(next_token(&args));
    int32_t n = unhex(next_token(&args), bytes);
    puts_("= ");
    vt_send_frame(type, seq, bytes, n > 0 ? (uint16_t)n : 0);
}

static void cmd_outputs(void)
{
    puts_("=");
#if VT_RUNNER_OUTPUTS
    for (uint16_t i = 0; i < VT_MAX_ACTUATORS; i++) {
        const vt_setting *s = &outputs[i];
        if (!s->a)
            continue;
        vt_runner_putc(' ');
        put_dec(i);
        vt_runner_putc(':');
        put_dec(s->a);
        vt_runner_putc(',');
        put_dec(s->f);
        vt_runner_putc(',');
        put_dec(s->w);
    }
#endif
}

void vt_runner_run(void)
{
    for (;;) {
        uint16_t n = 0;
        int c;
        while ((c = vt_runner_getc()) >= 0 && c != '\n') {
            if (c != '\r' && n < sizeof line - 1)
                line[n++] = (char)c;
        }
        if (c < 0 && n == 0)
            return;
        line[n] = 0;
        char *args = line;
        char *cmd = next_token(&args);
        if (!cmd) {
            if (c < 0)
                return;
            continue;
        }
        if (!strcmp(cmd, "config"))
            cmd_config(args);
        else if (!strcmp(cmd, "at"))
            cmd_at(args, 1);
        else if (!strcmp(cmd, "tick"))
            cmd_at(args, 0);
        else if (!strcmp(cmd, "crc"))
            cmd_crc(args);
        else if (!strcmp(cmd, "cobs"))
            cmd_cobs(args);
        else if (!strcmp(cmd, "uncobs"))
            cmd_uncobs(args);
        else if (!strcmp(cmd, "frame"))
            cmd_frame(args);
        else if (!strcmp(cmd, "outputs"))
            cmd_outputs();
        else
            puts_("! unknown command");
        vt_runner_putc('\n');
        if (c < 0)
            return;
    }
}
