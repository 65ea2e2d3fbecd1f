/* The portable core of the vtexp reference firmware (see vt_core.h).
 *
 * Section numbers in comments refer to docs/protocol.md. The Python model of the
 * same device, vtexp/devices/firmware.py, passes the same vectors; where this
 * file does something differently (allowed by the document) the comment says so.
 */
#include <string.h>

#include "vt_cobs.h"
#include "vt_core.h"
#include "vt_crc32.h"
#include "vt_hal.h"
#include "vt_profile.h"
#include "vt_wire.h"

#if VT_MAX_PULSES <= 256
typedef uint8_t vt_pidx;          /* a pulse number; 8 bits where it fits, for RAM */
#else
typedef uint16_t vt_pidx;
#endif

#define PULSE_BYTES (10 + VT_SETTING_BYTES)    /* index u16, onset u32, duration u32, setting */
#define RX_CAP (VT_MAX_PAYLOAD + VT_MIN_FRAME)
#define CACHE_RAW 32                           /* type + payload of the largest cached reply */

enum { CACHE_NONE, CACHE_RAW_REPLY, CACHE_ONSETS };

static struct vt_state {
    const vt_config *cfg;
    uint16_t n_act;
    vt_counters c;

    /* session (§ Session, heartbeat, watchdog) */
    uint8_t session;
    uint16_t heartbeat_ms, watchdog_ms;
    uint32_t watchdog_us;
    uint64_t last_rx_us;
    uint8_t tx_seq;

    /* receiving: COBS decoded in place as bytes arrive (§ Frames) */
    uint8_t rx[RX_CAP];
    vt_cobs_dec dec;

    /* the reply cache: the last executed request's length and CRC, and its reply */
    uint8_t cache_valid, cache_kind, cache_seq, cache_raw_len, capturing;
    uint16_t cache_req_len;
    uint32_t cache_req_crc;
    uint8_t cache_raw[CACHE_RAW];
    uint8_t cache_ack_seq;
    uint16_t cache_pid, cache_first, cache_k;

    /* an event a request causes, sent after its reply */
    uint8_t ev_done, ev_reason;
    uint16_t ev_pid, ev_n;
    uint64_t ev_t;

    /* the one schedule slot (§ Schedules) */
    uint8_t uploading, loaded;
    uint16_t up_id, up_n, up_got, loaded_id, n_pulses;
    uint8_t sched[VT_MAX_PULSES * PULSE_BYTES];

    /* the play: armed, then playing */
    uint8_t playing, started, pending;
    uint16_t play_id, next_on, heap_n, pend_first, pend_count;
    uint64_t start_us, last_change_us;
    vt_pidx heap[VT_MAX_PULSES];              /* pulses on, by (end, number) */
    uint8_t act_cnt[VT_MAX_ACTUATORS];        /* pulses on, per actuator */

    /* the onsets of one play: the one in progress, or else the last one */
    uint8_t op_valid;
    uint16_t op_id, op_n, op_count;
    uint64_t op_start;
    uint32_t onsets[VT_MAX_PULSES];           /* from op_start; VT_NOT_PLAYED_U32 if none */
} S;

#ifdef VT_RAM_LIMIT
/* A profile whose capacities do not fit the chip stops the build here, not in the lab. */
_Static_assert(sizeof(struct vt_state) + VT_PORT_RAM_BYTES + VT_STACK_RESERVE <= VT_RAM_LIMIT,
               "the capacities of this profile exceed the RAM of the chip: build with a smaller "
               "VT_MAX_PULSES or VT_MAX_PAYLOAD (docs/firmware.md, \"RAM and flash\")");
#endif

static const vt_setting OFF = {0, 0, 0, 0};

/* ------------------------------------------------------------------ little-endian */

static uint16_t rd16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }

static uint32_t rd32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static uint64_t rd64(const uint8_t *p) { return (uint64_t)rd32(p) | ((uint64_t)rd32(p + 4) << 32); }

/* ------------------------------------------------------------------ sending (§ Frames) */

static uint32_t enc_crc;

static void put8(uint8_t b)
{
    enc_crc = vt_crc32_update(enc_crc, b);
    vt_cobs_enc_byte(b);
    if (S.capturing && S.cache_raw_len < CACHE_RAW)
        S.cache_raw[S.cache_raw_len++] = b;
}

static void put16(uint16_t v) { put8((uint8_t)v); put8((uint8_t)(v >> 8)); }
static void put32(uint32_t v) { put16((uint16_t)v); put16((uint16_t)(v >> 16)); }
static void put64(uint64_t v) { put32((uint32_t)v); put32((uint32_t)(v >> 32)); }

static void put_text(const char *s)
{
    size_t n = s ? strlen(s) : 0;
    if (n > 255)
        n = 255;
    put8((uint8_t)n);
    for (size_t i = 0; i < n; i++)
        put8((uint8_t)s[i]);
}

/* Start a frame numbered seq. While a request is executed, the reply's type and
 * payload are captured for the cache. */
static void frame_begin_seq(uint8_t type, uint8_t seq)
{
    uint8_t capturing = S.capturing;
    S.capturing = 0;
    vt_hal_tx(0);                             /* ends any garbage the host may hold */
    vt_cobs_enc_begin();
    enc_crc = VT_CRC_INIT;
    put8(VT_PROTOCOL);
    put8(type);
    put8(seq);
    S.capturing = capturing;
    if (capturing) {
        S.cache_seq = seq;
        S.cache_raw_len = 0;
        S.cache_raw[S.cache_raw_len++] = type;
        S.cache_kind = CACHE_RAW_REPLY;
    }
}

static void frame_begin(uint8_t type) { frame_begin_seq(type, S.tx_seq++); }

static void frame_end(void)
{
    uint32_t crc = enc_crc ^ 0xFFFFFFFFUL;
    S.capturing = 0;
    for (uint8_t i = 0; i < 4; i++)
        vt_cobs_enc_byte((uint8_t)(crc >> (8 * i)));
    vt_cobs_enc_end();
    vt_hal_tx(0);
}

void vt_send_frame(uint8_t type, uint8_t seq, const uint8_t *payload, uint16_t n)
{
    uint8_t capturing = S.capturing;
    S.capturing = 0;
    frame_begin_seq(type, seq);
    S.capturing = 0;
    for (uint16_t i = 0; i < n; i++)
        put8(payload[i]);
    frame_end();
    S.capturing = capturing;
}

static void send_ack(uint8_t seq, uint64_t t)
{
    frame_begin(VT_ACK);
    put8(seq);
    put64(t);
    frame_end();
}

static void send_nak(uint8_t seq, uint8_t reason, uint16_t detail)
{
    frame_begin(VT_NAK);
    put8(seq);
    put8(reason);
    put16(detail);
    frame_end();
}

static void send_onset(uint16_t pid, uint16_t first, uint16_t count, uint64_t t)
{
    frame_begin(VT_ONSET);
    put16(pid);
    put16(first);
    put16(count);
    put64(t);
    frame_end();
}

static void send_play_done(uint16_t pid, uint8_t reason, uint16_t n, uint64_t t)
{
    frame_begin(VT_PLAY_DONE);
    put16(pid);
    put8(reason);
    put16(n);
    put64(t);
    frame_end();
}

static void onsets_payload(uint8_t ack_seq, uint16_t pid, uint16_t first, uint16_t k)
{
    put8(ack_seq);
    put16(pid);
    put16(first);
    for (uint16_t i = first; i < (uint16_t)(first + k); i++) {
        uint32_t rel = S.onsets[i];
        put64(rel == VT_NOT_PLAYED_U32 ? UINT64_MAX : S.op_start + rel);
    }
}

/* ------------------------------------------------------------------ settings and pulses */

static uint8_t setting_size(uint8_t drive) { return drive == VT_DRIVE_LEVEL ? 1 : 6; }

static vt_setting read_setting(uint8_t drive, const uint8_t *p)
{
    vt_setting s = {0, 0, 0, 0};
    if (drive == VT_DRIVE_LEVEL) {
        s.a = p[0];
    } else {
        s.a = rd16(p);
        s.f = rd16(p + 2);
        s.w = rd16(p + 4);
    }
    return s;
}

/* Within the hardware (§ Actuators and settings); the profile's safety limits are
 * the host's business. */
static uint8_t setting_ok(const vt_setting *s)
{
    const vt_config *c = S.cfg;
    if (c->drive == VT_DRIVE_LEVEL)
        return s->a <= c->max_level;
    if (s->a == 0)
        return 1;                             /* off, whatever the rest says */
    return s->a <= c->max_amplitude_mv && s->f > 0 && s->f <= c->max_frequency_chz && s->w > 0
        && s->w <= c->max_width_us && (uint32_t)s->w * s->f < 100000000UL;
}

static const uint8_t *pulse_at(uint16_t j) { return &S.sched[(uint32_t)j * PULSE_BYTES]; }
static uint16_t p_index(uint16_t j) { return rd16(pulse_at(j)); }
static uint32_t p_onset(uint16_t j) { return rd32(pulse_at(j) + 2); }
static uint32_t p_end(uint16_t j) { return p_onset(j) + rd32(pulse_at(j) + 6); }

static vt_setting p_setting(uint16_t j)
{
    const uint8_t *p = pulse_at(j) + 10;
#if VT_SETTING_BYTES == 1
    vt_setting s = {p[0], 0, 0, 0};
    return s;
#else
    return read_setting(S.cfg->drive, p);
#endif
}

/* ------------------------------------------------------------------ the heap of pulses on */

static uint8_t heap_less(vt_pidx x, vt_pidx y)
{
    uint32_t ex = p_end(x), ey = p_end(y);
    return ex < ey || (ex == ey && x < y);
}

static void heap_push(vt_pidx j)
{
    uint16_t i = S.heap_n++;
    while (i > 0) {
        uint16_t up = (uint16_t)((i - 1) / 2);
        if (!heap_less(j, S.heap[up]))
            break;
        S.heap[i] = S.heap[up];
        i = up;
    }
    S.heap[i] = j;
}

static vt_pidx heap_pop(void)
{
    vt_pidx top = S.heap[0];
    vt_pidx last = S.heap[--S.heap_n];
    uint16_t i = 0;
    for (;;) {
        uint16_t l = (uint16_t)(2 * i + 1), r = (uint16_t)(l + 1), m = i;
        vt_pidx best = last;
        if (l < S.heap_n && heap_less(S.heap[l], best)) {
            m = l;
            best = S.heap[l];
        }
        if (r < S.heap_n && heap_less(S.heap[r], best))
            m = r;
        if (m == i)
            break;
        S.heap[i] = S.heap[m];
        i = m;
    }
    if (S.heap_n)
        S.heap[i] = last;
    return top;
}

/* ------------------------------------------------------------------ outputs and plays */

static void set_deadline(void)
{
    vt_hal_set_deadline(S.session ? S.last_rx_us + S.watchdog_us : VT_NO_DEADLINE);
}

static void stop_play(void)
{
    S.playing = 0;
    S.pending = 0;
    S.heap_n = 0;
    memset(S.act_cnt, 0, S.n_act);
}

/* Every output off now; a play stops, its PLAY_DONE queued after the reply. */
static uint64_t all_off(uint8_t reason)
{
    vt_hal_all_off();
    uint64_t t = vt_hal_now_us();
    if (S.playing) {
        S.ev_done = 1;
        S.ev_pid = S.play_id;
        S.ev_reason = reason;
        S.ev_n = S.op_count;
        S.ev_t = t;
        stop_play();
    }
    return t;
}

static void send_events(void)
{
    if (S.ev_done) {
        S.ev_done = 0;
        send_play_done(S.ev_pid, S.ev_reason, S.ev_n, S.ev_t);
    }
}

static void trip_watchdog(void)
{
    uint64_t t = all_off(VT_DONE_WATCHDOG);
    S.session = 0;
    S.cache_valid = 0;                        /* a late retry must hear NO_SESSION */
    S.c.watchdog_trips++;
    set_deadline();
    send_events();
    frame_begin(VT_ALARM);
    put8(VT_ALARM_WATCHDOG);
    put64(t);
    frame_end();
}

static uint8_t watchdog_expired(void)
{
    return S.session && vt_hal_now_us() - S.last_rx_us > S.watchdog_us;
}

/* The next instant of the play, from its start: an onset or an end. */
static uint8_t next_instant(uint32_t *T)
{
    uint8_t any = 0;
    if (S.next_on < S.n_pulses) {
        *T = p_onset(S.next_on);
        any = 1;
    }
    if (S.heap_n) {
        uint32_t e = p_end(S.heap[0]);
        if (!any || e < *T)
            *T = e;
        any = 1;
    }
    return any;
}

/* Stage instant T: ends first, then onsets (§ Schedules, "Playing"). */
static void stage_instant(uint32_t T, uint16_t *n_on)
{
    while (S.heap_n && p_end(S.heap[0]) == T) {
        vt_pidx j = heap_pop();
        uint16_t a = p_index(j);
        if (--S.act_cnt[a] == 0) {
            vt_hal_stage(a, &OFF);
            continue;
        }
        /* Another pulse is still on this actuator: the latest started of those that go
         * on past T drives it (if they all end at T too, the last of them turns it off). */
        int32_t best = -1;
        for (uint16_t h = 0; h < S.heap_n; h++) {
            vt_pidx k = S.heap[h];
            if (p_index(k) == a && p_end(k) > T && (int32_t)k > best)
                best = k;
        }
        if (best >= 0) {
            vt_setting s = p_setting((uint16_t)best);
            s.d = p_end((uint16_t)best) - T;
            vt_hal_stage(a, &s);
        }
    }
    while (S.next_on < S.n_pulses && p_onset(S.next_on) == T) {
        uint16_t j = S.next_on++;
        uint16_t a = p_index(j);
        vt_setting s = p_setting(j);
        s.d = p_end(j) - T;
        S.act_cnt[a]++;
        vt_hal_stage(a, &s);
        heap_push((vt_pidx)j);
        (*n_on)++;
    }
}

static void play_poll(void)
{
    while (S.playing) {
        if (S.pending) {
            uint64_t t;
            if (!vt_hal_committed(&t))
                return;
            S.pending = 0;
            S.started = 1;
            S.last_change_us = t;
            if (S.pend_count) {
                for (uint16_t i = S.pend_first; i < S.pend_first + S.pend_count; i++)
                    S.onsets[i] = (uint32_t)(t - S.start_us);
                S.op_count += S.pend_count;
                send_onset(S.play_id, S.pend_first, S.pend_count, t);
            }
        }
        uint32_t T;
        if (!next_instant(&T)) {
            uint64_t t = S.last_change_us;
            if (S.n_pulses == 0) {            /* an empty schedule finishes at its start */
                t = vt_hal_now_us();
                if (t < S.start_us)
                    return;
            }
            S.playing = 0;
            S.started = 1;
            send_play_done(S.play_id, VT_DONE_FINISHED, S.op_count, t);
            return;
        }
        uint64_t due = S.start_us + T;
        uint64_t when = vt_hal_commit_time(due);
#if !VT_HAL_SCHEDULES_COMMITS
        if (vt_hal_now_us() < due)
            return;                           /* this port applies a set when it is due */
#endif
        /* Instants that the outputs will show in one change are staged as one set: those
         * in one tick of an output clock, or all that are due if the device fell behind. */
        uint16_t first = S.next_on, n_on = 0;
        vt_hal_stage_begin();
        do {
            stage_instant(T, &n_on);
        } while (next_instant(&T) && vt_hal_commit_time(S.start_us + T) == when);
        vt_hal_commit_at(due, n_on != 0);
        S.pending = 1;
        S.pend_first = first;
        S.pend_count = n_on;
    }
}

/* ------------------------------------------------------------------ requests */

static uint16_t clamp_ms(uint16_t v)
{
    const vt_config *c = S.cfg;
    return v < c->min_watchdog_ms ? c->min_watchdog_ms : v > c->max_watchdog_ms ? c->max_watchdog_ms : v;
}

static void do_hello(uint8_t seq, const uint8_t *p)
{
    const vt_config *c = S.cfg;
    uint8_t protocol = p[0];
    if (protocol < 1) {
        send_nak(seq, VT_NAK_UNSUPPORTED_PROTOCOL, VT_PROTOCOL);
        return;
    }
    all_off(VT_DONE_ALL_OFF);
    S.heartbeat_ms = clamp_ms(rd16(p + 1));
    S.watchdog_ms = clamp_ms(rd16(p + 3));
    S.watchdog_us = (uint32_t)S.watchdog_ms * 1000u;
    S.session = 1;
    S.last_rx_us = vt_hal_now_us();
    set_deadline();
    S.uploading = S.loaded = 0;
    S.op_valid = 0;                           /* the last play's onsets go with the session */
    S.cache_kind = CACHE_NONE;                /* HELLO is always executed again */
    frame_begin(VT_HELLO_REPLY);
    S.cache_kind = CACHE_NONE;
    put8(seq);
    put8(protocol < VT_PROTOCOL ? protocol : VT_PROTOCOL);
    put16(S.heartbeat_ms);
    put16(S.watchdog_ms);
    put16(c->rows);
    put16(c->cols);
    put8(c->actuator);
    put8(c->drive);
    put8(c->max_level);
    put16(c->max_amplitude_mv);
    put16(c->max_frequency_chz);
    put16(c->max_width_us);
    put16(c->max_pulses);
    put16(c->max_payload);
    put64(vt_hal_now_us());
    put_text(c->firmware);
    put_text(c->device_id);
    frame_end();
}

static void do_status(uint8_t seq)
{
    frame_begin(VT_STATUS_REPLY);
    put8(seq);
    put8(vt_state());
    put16(S.op_valid ? S.op_id : 0);
    put16(S.op_valid ? S.op_count : 0);
    put64(vt_hal_now_us());
    put32(S.c.rx_frames);
    put32(S.c.rx_bad);
    put32(S.c.duplicates);
    put16(S.c.watchdog_trips);
    frame_end();
}

/* Refusals that several requests share; each is nonzero once its NAK is sent. */
static uint8_t refused_while_playing(uint8_t seq)
{
    if (!S.playing)
        return 0;
    send_nak(seq, VT_NAK_BUSY, S.play_id);
    return 1;
}

static uint8_t refused_for_drive(uint8_t seq, uint8_t drive)
{
    if (drive == S.cfg->drive)
        return 0;
    send_nak(seq, VT_NAK_WRONG_DRIVE, S.cfg->drive);
    return 1;
}

static void do_set_frame(uint8_t seq, uint8_t type, const uint8_t *p, uint16_t plen)
{
    uint8_t drive = p[0];
    if (refused_while_playing(seq) || refused_for_drive(seq, drive))
        return;
    uint8_t size = setting_size(drive);
    uint16_t count;
    const uint8_t *q;
    uint8_t stride;
    if (type == VT_SET_FRAME_FULL) {
        count = (uint16_t)((plen - 1) / size);
        if (count != S.n_act) {
            send_nak(seq, VT_NAK_BAD_PAYLOAD, S.n_act);
            return;
        }
        q = p + 1;
        stride = size;
    } else {
        count = rd16(p + 1);
        q = p + 3;
        stride = (uint8_t)(2 + size);
    }
    /* everything is checked before any output changes */
    for (uint16_t k = 0; k < count; k++) {
        const uint8_t *e = q + (uint32_t)k * stride;
        uint16_t index = type == VT_SET_FRAME_FULL ? k : rd16(e);
        vt_setting s = read_setting(drive, type == VT_SET_FRAME_FULL ? e : e + 2);
        if (index >= S.n_act || !setting_ok(&s)) {
            send_nak(seq, VT_NAK_OUT_OF_RANGE, index);
            return;
        }
    }
    vt_hal_stage_begin();
    for (uint16_t k = 0; k < count; k++) {
        const uint8_t *e = q + (uint32_t)k * stride;
        uint16_t index = type == VT_SET_FRAME_FULL ? k : rd16(e);
        vt_setting s = read_setting(drive, type == VT_SET_FRAME_FULL ? e : e + 2);
        vt_hal_stage(index, &s);
    }
    send_ack(seq, vt_hal_commit_now());
}

static void do_upload_begin(uint8_t seq, const uint8_t *p)
{
    uint16_t pid = rd16(p), n = rd16(p + 2);
    uint8_t drive = p[4];
    if (refused_while_playing(seq) || refused_for_drive(seq, drive))
        return;
    if (n > S.cfg->max_pulses) {
        send_nak(seq, VT_NAK_TOO_LARGE, S.cfg->max_pulses);
        return;
    }
    if (n > VT_MAX_PULSES) {                  /* only a test build reports more than it holds */
        send_nak(seq, VT_NAK_TOO_LARGE, VT_MAX_PULSES);
        return;
    }
    S.uploading = 1;                          /* the one slot: the previous schedule is gone */
    S.loaded = 0;
    S.up_id = pid;
    S.up_n = n;
    S.up_got = 0;
    if (n == 0) {
        S.uploading = 0;
        S.loaded = 1;
        S.loaded_id = pid;
        S.n_pulses = 0;
    }
    send_ack(seq, vt_hal_now_us());
}

static void do_upload_chunk(uint8_t seq, const uint8_t *p, uint16_t plen)
{
    uint16_t pid = rd16(p), first = rd16(p + 2);
    uint8_t drive = p[4];
    if (!S.uploading || pid != S.up_id) {
        send_nak(seq, VT_NAK_NO_SCHEDULE, pid);
        return;
    }
    if (refused_for_drive(seq, drive))
        return;
    if (first != S.up_got) {
        send_nak(seq, VT_NAK_OUT_OF_ORDER, S.up_got);
        return;
    }
    uint8_t size = (uint8_t)(10 + setting_size(drive));
    uint16_t k = (uint16_t)((plen - 5) / size);
    if ((uint32_t)S.up_got + k > S.up_n) {
        send_nak(seq, VT_NAK_TOO_LARGE, S.up_n);
        return;
    }
    uint32_t prev = S.up_got ? p_onset((uint16_t)(S.up_got - 1)) : 0;
    for (uint16_t i = 0; i < k; i++) {
        const uint8_t *e = p + 5 + (uint32_t)i * size;
        uint16_t index = rd16(e);
        uint32_t onset = rd32(e + 2), dur = rd32(e + 6);
        vt_setting s = read_setting(drive, e + 10);
        if (index >= S.n_act || !setting_ok(&s) || dur == 0 || dur > 0xFFFFFFFFUL - onset) {
            send_nak(seq, VT_NAK_OUT_OF_RANGE, index);
            return;
        }
        if (onset < prev) {
            send_nak(seq, VT_NAK_OUT_OF_ORDER, (uint16_t)(first + i));
            return;
        }
        prev = onset;
    }
    for (uint16_t i = 0; i < k; i++) {
        const uint8_t *e = p + 5 + (uint32_t)i * size;
        uint8_t *d = &S.sched[(uint32_t)(S.up_got + i) * PULSE_BYTES];
        memcpy(d, e, 10);
        memcpy(d + 10, e + 10, VT_SETTING_BYTES < setting_size(drive) ? VT_SETTING_BYTES
                                                                     : setting_size(drive));
    }
    S.up_got = (uint16_t)(S.up_got + k);
    if (S.up_got == S.up_n) {
        S.uploading = 0;
        S.loaded = 1;
        S.loaded_id = S.up_id;
        S.n_pulses = S.up_n;
    }
    send_ack(seq, vt_hal_now_us());
}

static void do_trigger(uint8_t seq, const uint8_t *p)
{
    uint16_t pid = rd16(p);
    uint64_t at = rd64(p + 2);
    if (refused_while_playing(seq))
        return;
    if (!S.loaded || S.loaded_id != pid) {
        send_nak(seq, VT_NAK_NO_SCHEDULE, pid);
        return;
    }
    uint64_t now = vt_hal_now_us();
    uint64_t start = vt_hal_align_start(at && at > now ? at : now);
    S.playing = 1;
    S.started = 0;
    S.pending = 0;
    S.play_id = pid;
    S.start_us = start;
    S.last_change_us = start;
    S.next_on = 0;
    S.heap_n = 0;
    memset(S.act_cnt, 0, S.n_act);
    /* one play's onsets are kept: from now on, this one's */
    S.op_valid = 1;
    S.op_id = pid;
    S.op_n = S.n_pulses;
    S.op_start = start;
    S.op_count = 0;
    for (uint16_t i = 0; i < S.n_pulses; i++)
        S.onsets[i] = VT_NOT_PLAYED_U32;
#if VT_HAL_SCHEDULES_COMMITS
    /* A port that applies sets itself gets the first instant now, before the reply is
     * queued: the start it chose leaves room for this, not for other frames too. No
     * event can come of it before the reply: the set goes out at its tick. */
    play_poll();
#endif
    send_ack(seq, start);
}

static void do_get_onsets(uint8_t seq, const uint8_t *p)
{
    uint16_t pid = rd16(p), first = rd16(p + 2), count = rd16(p + 4);
    if (!S.op_valid || S.op_id != pid) {
        send_nak(seq, VT_NAK_NO_SCHEDULE, pid);
        return;
    }
    uint16_t fit = S.cfg->max_payload >= 5 ? (uint16_t)((S.cfg->max_payload - 5) / 8) : 0;
    uint16_t k = count < fit ? count : fit;
    if (first >= S.op_n)
        k = 0;
    else if (k > S.op_n - first)
        k = (uint16_t)(S.op_n - first);
    frame_begin(VT_ONSETS_REPLY);
    /* not stored: rebuilt from the onset table if the request is repeated */
    S.cache_kind = CACHE_ONSETS;
    S.cache_ack_seq = seq;
    S.cache_pid = pid;
    S.cache_first = first;
    S.cache_k = k;
    S.capturing = 0;
    onsets_payload(seq, pid, first, k);
    frame_end();
}

static void execute(uint8_t seq, uint8_t type, const uint8_t *p, uint16_t plen)
{
    switch (type) {
    case VT_HELLO:
        do_hello(seq, p);
        return;
    case VT_ALL_OFF:                          /* always allowed: abort means off */
        send_ack(seq, all_off(VT_DONE_ALL_OFF));
        return;
    case VT_BYE: {                            /* a clean goodbye: off, session over */
        uint64_t t = all_off(VT_DONE_ALL_OFF);
        S.session = 0;
        set_deadline();
        send_ack(seq, t);
        return;
    }
    case VT_STATUS:
        do_status(seq);
        return;
    case VT_GET_ONSETS:                       /* read-only: after a watchdog trip the host */
        do_get_onsets(seq, p);                /* recovers the play's onsets before HELLO */
        return;
    }
    if (!S.session) {
        send_nak(seq, VT_NAK_NO_SESSION, 0);
        return;
    }
    switch (type) {
    case VT_HEARTBEAT:
        send_ack(seq, vt_hal_now_us());
        break;
    case VT_SET_FRAME:
    case VT_SET_FRAME_FULL:
        do_set_frame(seq, type, p, plen);
        break;
    case VT_UPLOAD_BEGIN:
        do_upload_begin(seq, p);
        break;
    case VT_UPLOAD_CHUNK:
        do_upload_chunk(seq, p, plen);
        break;
    case VT_TRIGGER:
        do_trigger(seq, p);
        break;
    }
}

static void resend_cached(void)
{
    if (S.cache_kind == CACHE_ONSETS) {
        frame_begin_seq(VT_ONSETS_REPLY, S.cache_seq);
        onsets_payload(S.cache_ack_seq, S.cache_pid, S.cache_first, S.cache_k);
        frame_end();
    } else if (S.cache_kind == CACHE_RAW_REPLY) {
        frame_begin_seq(S.cache_raw[0], S.cache_seq);
        for (uint8_t i = 1; i < S.cache_raw_len; i++)
            put8(S.cache_raw[i]);
        frame_end();
    }
}

/* The form of each request's payload (§ Messages): exact lengths, known drive kinds. */
static uint8_t payload_ok(uint8_t type, const uint8_t *p, uint16_t n)
{
    switch (type) {
    case VT_HELLO:
    case VT_UPLOAD_BEGIN:
        return n == 5;
    case VT_HEARTBEAT:
    case VT_ALL_OFF:
    case VT_STATUS:
    case VT_BYE:
        return n == 0;
    case VT_TRIGGER:
        return n == 10;
    case VT_GET_ONSETS:
        return n == 6;
    case VT_SET_FRAME:
        if (n < 3 || (p[0] != VT_DRIVE_LEVEL && p[0] != VT_DRIVE_TRAIN))
            return 0;
        return (uint32_t)n == 3u + (uint32_t)rd16(p + 1) * (2u + setting_size(p[0]));
    case VT_SET_FRAME_FULL:
        if (n < 1 || (p[0] != VT_DRIVE_LEVEL && p[0] != VT_DRIVE_TRAIN))
            return 0;
        return (n - 1) % setting_size(p[0]) == 0;
    case VT_UPLOAD_CHUNK:
        if (n < 5 || (p[4] != VT_DRIVE_LEVEL && p[4] != VT_DRIVE_TRAIN))
            return 0;
        return (n - 5) % (10 + setting_size(p[4])) == 0;
    }
    return 0;
}

static void bad(uint8_t seq, uint8_t reason, uint16_t detail)
{
    S.c.rx_bad++;
    send_nak(seq, reason, detail);
}

/* A delimiter: the bytes since the last one are a frame (§ Frames the device cannot act on). */
static void rx_frame(void)
{
    int16_t n = vt_cobs_dec_end(&S.dec);
    if (n == VT_COBS_EMPTY)
        return;                               /* two zeros in a row */
    uint16_t len = n > 0 ? (uint16_t)n : 0;
    /* A frame that arrives after the watchdog's deadline is too late to save the
     * session: the deadline passed first (a timer interrupt would have seen it). */
    if (watchdog_expired())
        trip_watchdog();
    if (n < VT_MIN_FRAME) {                   /* bad COBS, too long, or too short */
        bad(0, VT_NAK_BAD_FRAME, 0);
        return;
    }
    uint32_t crc = rd32(&S.rx[len - 4]);
    if (vt_crc32(S.rx, (size_t)(len - 4)) != crc) {
        bad(0, VT_NAK_BAD_FRAME, 0);
        return;
    }
    uint8_t version = S.rx[0], type = S.rx[1], seq = S.rx[2];
    const uint8_t *p = &S.rx[3];
    uint16_t plen = (uint16_t)(len - VT_MIN_FRAME);
    if (version != VT_PROTOCOL) {
        bad(0, VT_NAK_BAD_VERSION, VT_PROTOCOL);
        return;
    }
    if (type < VT_HELLO || type > VT_BYE) {   /* unknown, or a reply or event sent to us */
        bad(seq, VT_NAK_UNKNOWN_TYPE, type);
        return;
    }
    if (!payload_ok(type, p, plen)) {
        bad(seq, VT_NAK_BAD_PAYLOAD, 0);
        return;
    }
    S.c.rx_frames++;
    if (S.session) {
        S.last_rx_us = vt_hal_now_us();       /* a valid request feeds the watchdog */
        set_deadline();
    }
    if (type != VT_HELLO && S.cache_valid && S.cache_req_len == len && S.cache_req_crc == crc) {
        S.c.duplicates++;                     /* a retry: answer again, do not act again */
        resend_cached();
        return;
    }
    S.capturing = 1;
    S.cache_kind = CACHE_NONE;
    execute(seq, type, p, plen);
    S.capturing = 0;
    S.cache_valid = 1;
    S.cache_req_len = len;
    S.cache_req_crc = crc;
    send_events();
}

/* ------------------------------------------------------------------ the interface */

void vt_init(const vt_config *cfg)
{
    memset(&S, 0, sizeof S);
    S.cfg = cfg;
    S.n_act = (uint16_t)(cfg->rows * cfg->cols);
    if (S.n_act > VT_MAX_ACTUATORS)
        S.n_act = VT_MAX_ACTUATORS;           /* a profile header never allows this */
    uint16_t payload = cfg->max_payload < VT_MAX_PAYLOAD ? cfg->max_payload : VT_MAX_PAYLOAD;
    vt_cobs_dec_init(&S.dec, S.rx, (uint16_t)(payload + VT_MIN_FRAME));
    vt_hal_all_off();
    set_deadline();
}

void vt_rx_byte(uint8_t b)
{
    if (b == 0)
        rx_frame();
    else
        vt_cobs_dec_byte(&S.dec, b);
}

void vt_poll(void)
{
    if (watchdog_expired()) {
        trip_watchdog();
        return;
    }
    play_poll();
}

uint64_t vt_next_deadline_us(void)
{
    uint64_t d = VT_NEVER;
    uint32_t T;
    if (S.playing && !S.pending) {
        if (next_instant(&T))
            d = vt_hal_commit_time(S.start_us + T);
        else
            d = S.start_us;                   /* finishing: due now, or at an empty play's start */
    }
    if (S.session) {
        uint64_t w = S.last_rx_us + S.watchdog_us + 1;
        if (w < d)
            d = w;
    }
    return d;
}

const vt_counters *vt_get_counters(void) { return &S.c; }

uint8_t vt_state(void)
{
    if (!S.session)
        return VT_NO_SESSION;
    if (S.playing)
        return S.started ? VT_PLAYING : VT_ARMED;
    if (S.uploading)
        return VT_UPLOADING;
    return VT_IDLE;
}
