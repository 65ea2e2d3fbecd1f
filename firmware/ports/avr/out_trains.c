/* Pulse trains (SMA pins, seed 002): a logic-level MOSFET gate per pin, on whole
 * ports, and the pulse amplitude from daisy-chained LTC2656 octal DACs.
 *
 * A 10 kHz tick (100 us) carries the edges: a train set at T0 rises at
 * T0 + floor(k * 10^8 / f) us (f in 0.01 Hz) and falls width_us later, each edge at
 * the first tick at or after its time (docs/protocol.md, "What a pulse train is").
 * The period is kept as quotient and remainder so that no rounding accumulates.
 * Like the level drive's latch, the interrupt writes first the port values it
 * prepared at the previous tick (so every edge of a tick happens in one instant: 4
 * port writes, 0.25 us), then prepares the next tick, touching the pins only at
 * their edges.
 *
 * Amplitude: each pin's gate MOSFET switches the output of its own linear stage,
 * set by one DAC channel (pin i: chip i / 8, channel i % 8; full scale =
 * VT_FULL_SCALE_MV at the pin). A channel is written when its amplitude changes, ahead
 * of the commit (out_commit.c calls vt_out_commit_prepare): written and updated at once
 * if the pin is idle; if a train still runs on it, written to the channel's input
 * register only, and the commit's tick, after its edges, updates every channel of the
 * chips concerned from their input registers in one transfer (so the new amplitude is
 * on the pin one transfer, ~38 us, after the tick, however many channels change).
 *
 * LTC2656 word (32 bits for a daisy chain): 8 don't-care bits, command C3-C0,
 * address A3-A0, 12-bit code, 4 don't-care bits; command 0000 writes input register n,
 * 0001 updates DAC register n from it (address 1111: all eight), 0011 writes and
 * updates channel n, 1111 does nothing; the farthest chip's word is shifted first;
 * CS/LD rising executes them (LTC2656 datasheet, "Operation", Table 1). Every channel
 * written with 0000 is updated by the next 0001 to its chip, so a chip's input and DAC
 * registers differ only between a commit's preparation and its tick.
 */
#include "vt_profile.h"

#if VT_DRIVE == VT_DRIVE_TRAIN

#include <avr/interrupt.h>
#include <avr/io.h>
#include <string.h>

#include "avr_port.h"
#include "board.h"
#include "out_commit.h"
#include "vt_hal.h"

#define N VT_MAX_ACTUATORS
#define DAC_WRITE_INPUT 0x0
#define DAC_UPDATE 0x1
#define DAC_WRITE 0x3
#define DAC_NOP 0xF
#define DAC_ALL 0xF

typedef struct {             /* a train's timing, as the tick uses it */
    uint32_t q;              /* period: q + r / f us (10^8 / f and its remainder) */
    uint16_t r, f, w;        /* ... f in 0.01 Hz; the width in us */
    uint8_t wt, wrem;        /* the width: wt ticks, the last holding wrem us (1..tick) */
} train_t;

typedef struct {
    uint32_t edge;           /* time of the next edge, us (wrapping; compared by difference) */
    uint32_t rise;           /* the current pulse's rise */
    uint32_t until;          /* its schedule's end: no pulse rises at or after it */
    train_t t;
    uint16_t acc;            /* the period's remainder, accumulated */
    uint8_t on, high;
    uint8_t port, mask;      /* its gate: bit mask of byte port of the gate bytes */
    uint8_t fall_slot;       /* the fall ring's slot of the pulse it is in */
    uint8_t fresh;           /* its train started with a pulse of its own (not mid-pulse) */
    uint8_t bounded;         /* 1: until holds; 2: reached (no more pulses); 0: a frame's */
} pin_t;

typedef struct {
    uint16_t a;              /* the amplitude, mV (0: off) */
    uint32_t d;              /* how long it holds, us (0: until changed) */
    train_t t;               /* worked out when staged, out of the interrupt: it copies it */
} staged_t;

/* The fall ring: each pulse, when it rises, also writes its fall into the slot of the
 * tick it is due at, and the tick interrupt applies that slot itself before anything
 * else. A preparation that runs late (the next tick came first) delays edges by a tick;
 * with the ring, no pulse is ever longer for it: its fall happens on time, and the pin
 * is held off until a preparation has seen it fall. */
#define FALL_SLOTS 32
#define FALL_MASK (FALL_SLOTS - 1)
_Static_assert((VT_MAX_WIDTH_US + VT_TICK_US - 1) / VT_TICK_US + 2 <= FALL_SLOTS,
               "profile " VT_PROFILE_NAME ": a pulse longer than the fall ring");
_Static_assert(VT_TICK_US <= 255, "the last tick of a width is counted in a byte");

static pin_t pins[N];
static staged_t staged[N];
static uint32_t staged_mask;
static uint8_t staged_list[N], n_staged;     /* pins in the set being staged */
static pin_t *act[N];                         /* pins with a train, for the tick to visit */
static uint8_t n_act;
static pin_t *fell[N];                        /* pins a preparation turned off */
static uint8_t n_fell;
static uint8_t g_now[4];                      /* gates as the tick has prepared them */
static volatile uint8_t fall_ring[FALL_SLOTS][4];
static volatile uint8_t held_off[4];          /* fallen by the ring, not yet by a preparation */
static volatile uint8_t off_count;            /* times everything went off: seen mid-preparation */
static uint16_t dac_code[N];          /* what each channel holds */
static uint16_t dac_want[N];          /* what the committed set needs */

static volatile uint8_t out_a, out_c, out_l, out_g;   /* gates for the next tick */
static volatile uint32_t next_edge;   /* earliest edge of any pin, us */
static volatile uint8_t any_on;

static volatile uint8_t pre_commit, pre_sync;   /* the set committed (out_commit.c) goes
                                                 * out at the next tick, with sync */
/* The tick interrupt prepares the next tick (PREPARING) until it has left its gates in
 * out_* (PREPARED), then returns; a tick that comes meanwhile only asks for another
 * preparation (prepare_again), which the first runs before it returns. */
enum { IDLE, PREPARING, PREPARED };
static volatile uint8_t preparing;
static volatile uint8_t prepare_again;
volatile uint16_t vt_late_ticks;     /* ticks that came while the previous one was preparing */

static void gates(uint8_t a, uint8_t c, uint8_t l, uint8_t g)
{
    PORTA = a;
    PORTC = c;
    PORTL = l;
    PORTG = (uint8_t)((PORTG & ~1) | (g & 1));
}

void vt_out_safe(void)
{
    gates(0, 0, 0, 0);
    DDRA = 0xFF;
    DDRC = 0xFF;
    DDRL = 0xFF;
    DDRG |= 1;
}

#define DAC_XFER (4 * VT_DAC_CHIPS)               /* bytes of one transfer: a word a chip */
static uint8_t dac_xfer[8 * DAC_XFER];   /* transfers for a commit's tick, or to send now */
static volatile uint8_t n_dac_xfer;

_Static_assert(sizeof pins + sizeof staged + sizeof dac_code + sizeof dac_want + sizeof act
                       + sizeof fell + sizeof dac_xfer + sizeof fall_ring
                   <= VT_PORT_RAM_BYTES - 256 - 128 - 64,
               "profile " VT_PROFILE_NAME ": the train state exceeds the port's RAM budget");


/* Plan the transfers that give the pins in mask the codes they need with command cmd
 * (one channel per chip per transfer: a word per chip, the farthest first, NOP for the
 * others) into buf; returns how many, and the chips written in *chips (a bit each). The
 * codes count as written from now on. */
static uint8_t dac_plan(uint32_t mask, uint8_t cmd, uint8_t *buf, uint8_t max,
                        uint8_t *chips)
{
    uint8_t n = 0;
    *chips = 0;
    while (n < max) {
        int8_t channel[VT_DAC_CHIPS];
        uint16_t code[VT_DAC_CHIPS];
        uint8_t any = 0;
        for (uint8_t c = 0; c < VT_DAC_CHIPS; c++)
            channel[c] = -1;
        uint32_t bit = 1;
        for (uint8_t i = 0; i < N; i++, bit <<= 1) {
            uint8_t chip = (uint8_t)(i >> 3);
            if (!(mask & bit) || dac_code[i] == dac_want[i] || channel[chip] >= 0)
                continue;
            channel[chip] = (int8_t)(i & 7);
            code[chip] = dac_want[i];
            dac_code[i] = dac_want[i];
            *chips |= (uint8_t)(1 << chip);
            any = 1;
        }
        if (!any)
            break;
        uint8_t *w = buf + n * DAC_XFER;
        for (int8_t chip = VT_DAC_CHIPS - 1; chip >= 0; chip--) {
            uint8_t on = channel[chip] >= 0;
            uint16_t v = on ? (uint16_t)(code[chip] << 4) : 0;
            *w++ = 0;
            *w++ = (uint8_t)((on ? cmd : DAC_NOP) << 4 | (on ? channel[chip] : 0));
            *w++ = (uint8_t)(v >> 8);
            *w++ = (uint8_t)v;
        }
        n++;
    }
    return n;
}

/* Send planned transfers: CS/LD low, the bytes, CS/LD rising (the chips execute). */
static void dac_send(const uint8_t *buf, uint8_t n)
{
    for (uint8_t k = 0; k < n; k++) {
        LATCH_PORT &= (uint8_t)~_BV(LATCH_BIT);
        for (uint8_t i = 0; i < DAC_XFER; i++) {
            SPDR = buf[k * DAC_XFER + i];
            while (!(SPSR & _BV(SPIF)))
                ;
        }
        LATCH_PORT |= _BV(LATCH_BIT);
    }
}

/* Write now the channels of the pins in mask whose code differs from what they hold,
 * with command cmd; returns the chips written. Not while a set is committed: its update
 * waits in dac_xfer, planned here too (which keeps 128 bytes off the stack of the
 * commit's deepest call). */
static uint8_t dac_update(uint32_t mask, uint8_t cmd)
{
    uint8_t chips;
    dac_send(dac_xfer, dac_plan(mask, cmd, dac_xfer, 8, &chips));
    return chips;
}

/* The transfer that updates every channel of the chips in the mask from their input
 * registers (NOP for the other chips) into dac_xfer; returns 1, or 0 for no chip. */
static uint8_t dac_plan_update(uint8_t chips)
{
    if (!chips)
        return 0;
    uint8_t *w = dac_xfer;
    for (int8_t chip = VT_DAC_CHIPS - 1; chip >= 0; chip--) {
        uint8_t on = (chips >> chip) & 1;
        *w++ = 0;
        *w++ = (uint8_t)((on ? DAC_UPDATE : DAC_NOP) << 4 | (on ? DAC_ALL : 0));
        *w++ = 0;
        *w++ = 0;
    }
    return 1;
}

void vt_out_init(void)
{
    vt_out_safe();
    LATCH_PORT |= _BV(LATCH_BIT);             /* CS/LD idles high */
    SYNC_PORT &= (uint8_t)~_BV(SYNC_BIT);
    DDRB |= _BV(LATCH_BIT) | _BV(SYNC_BIT) | _BV(SPI_SS) | _BV(SPI_SCK) | _BV(SPI_MOSI);
    SPCR = _BV(SPE) | _BV(MSTR);              /* mode 0, MSB first */
    SPSR = _BV(SPI2X);
    memset(pins, 0, sizeof pins);
    for (uint8_t i = 0; i < N; i++) {
        pins[i].port = (uint8_t)(i >> 3);
        pins[i].mask = (uint8_t)(1 << (i & 7));
        dac_code[i] = 0xFFFF;                 /* unknown: every channel is written once */
        dac_want[i] = 0;
    }
    dac_update(0xFFFFFFFFUL, DAC_WRITE);
}

static uint16_t code_of(uint16_t mv)
{
    uint32_t c = ((uint32_t)mv * 4095u + VT_FULL_SCALE_MV / 2) / VT_FULL_SCALE_MV;
    return c > 4095 ? 4095 : (uint16_t)c;
}

/* A train from t0. On a pin in the middle of a pulse, that pulse goes on and falls when
 * it was to (its edge and fall slot stay): the new train's first pulse is the rest of it,
 * the next rises at t0 + a period. A pulse never outlasts the width it rose with. */
static void start_train(pin_t *p, const staged_t *st, uint32_t t0)
{
    uint8_t mid_pulse = p->on && p->high;
    p->on = 1;
    p->t = st->t;
    p->acc = 0;
    p->rise = t0;
    p->until = t0 + st->d;
    p->bounded = st->d != 0;
    p->fresh = !mid_pulse;
    if (!mid_pulse) {
        p->high = 0;
        p->edge = t0;                         /* the first pulse rises at once */
    }
}

/* Ticks from the tick at time t (that a pulse risen at rise <= t goes out at) to the
 * tick its fall is due at: the first at or after rise + width, and at least the next. */
static uint8_t fall_ticks(const pin_t *p, uint32_t t)
{
    uint32_t late = t - p->rise;
    if (late < p->t.wrem)
        return p->t.wt;                         /* the usual case: risen within this tick */
    if (late < VT_TICK_US)
        return p->t.wt > 1 ? (uint8_t)(p->t.wt - 1) : 1;
    if (late >= p->t.w)
        return 1;
    uint16_t left = (uint16_t)(p->t.w - late);
    uint8_t j = 0;
    while (left > VT_TICK_US) {
        left -= VT_TICK_US;
        j++;
    }
    return (uint8_t)(j + 1);
}

/* Advance the pins whose edge is due by time t, the time of tick kt (its low byte): the
 * gates for that tick, each rise's fall in the ring, and the next edge. Only pins with a
 * train are visited, so a tick costs what is on, not the array. */
static inline __attribute__((always_inline)) void advance(uint32_t t, uint8_t kt)
{
    uint32_t soonest = t + 0x7FFFFFFFUL;
    pin_t **a = act, **end = act + n_act;
    for (; a < end; a++) {
        pin_t *p = *a;
        uint32_t e = p->edge;
        if ((int32_t)(e - t) <= 0) {
            if (p->high) {                    /* fall; the next pulse rises a period later */
                p->high = 0;
                g_now[p->port] &= (uint8_t)~p->mask;
                fell[n_fell++] = p;
                uint32_t r = p->rise + p->t.q;
                p->acc += p->t.r;
                if (p->acc >= p->t.f) {
                    p->acc -= p->t.f;
                    r++;
                }
                p->rise = r;
                e = r;
            } else if (p->bounded && (int32_t)(p->rise - p->until) >= 0) {
                /* The train's end, as its schedule says: no pulse rises from here on,
                 * though the set that turns the pin off may come later (a preparation
                 * that ran late). It waits for that set with no edge due. */
                p->bounded = 2;
                continue;
            } else {
                p->high = 1;
                g_now[p->port] |= p->mask;
                e = p->rise + p->t.w;
                uint8_t at = (uint8_t)(kt + fall_ticks(p, t));
                p->fall_slot = at & FALL_MASK;
                cli();
                if ((int8_t)(at - (uint8_t)vt_ticks) > 0)
                    fall_ring[at & FALL_MASK][p->port] |= p->mask;
                else                          /* this preparation is so late that the
                                               * fall is past: the pulse never starts */
                    held_off[p->port] |= p->mask;
                sei();
            }
            p->edge = e;
        }
        if ((int32_t)(e - soonest) < 0)
            soonest = e;
    }
    next_edge = soonest;
    any_on = n_act != 0;
}

static void pin_off(pin_t *p)
{
    if (!p->on)
        return;
    if (p->high)
        fell[n_fell++] = p;                   /* its fall slot is cleared with the others */
    p->on = p->high = 0;
    g_now[p->port] &= (uint8_t)~p->mask;
    for (uint8_t k = 0; k < n_act; k++)
        if (act[k] == p) {
            act[k] = act[--n_act];
            break;
        }
}

static void gates_forgotten(void)
{
    g_now[0] = g_now[1] = g_now[2] = g_now[3] = 0;
    out_a = out_c = out_l = out_g = 0;
    held_off[0] = held_off[1] = held_off[2] = held_off[3] = 0;
    any_on = 0;
    n_act = 0;
}

/* Every pin off and forgotten, interrupts off: a pin in a pulse has one fall in the ring,
 * at its fall slot (those a preparation turned off are cleared when it ends), so only
 * the pins with a train are visited. */
static void all_pins_off(void)
{
    for (uint8_t k = 0; k < n_act; k++) {
        pin_t *p = act[k];
        if (p->high)
            fall_ring[p->fall_slot][p->port] &= (uint8_t)~p->mask;
        p->on = p->high = 0;
    }
    gates_forgotten();
    off_count++;
}

/* The same, whatever state a preparation cut short by it left (interrupts off). */
static void all_pins_wiped(void)
{
    for (uint8_t i = 0; i < N; i++)
        pins[i].on = pins[i].high = 0;
    memset((void *)fall_ring, 0, sizeof fall_ring);
    gates_forgotten();
}

/* The preparation of the next tick: called with interrupts off, returns with them on. */
static void __attribute__((noinline)) prepare(void)
{
    uint32_t k = vt_ticks;                    /* the tick now */
    uint8_t offs = off_count;
    n_fell = 0;
    sei();
    /* The next tick: a committed set starts there, and edges due by then happen there. */
    uint32_t t_next = vt_tick_us_lo + VT_TICK_US;             /* us, wrapping */
    uint8_t commit = vt_commit_due(k);
    if (commit) {
        for (uint8_t j = 0; j < n_staged; j++) {
            uint8_t i = staged_list[j];
            pin_t *p = &pins[i];
            if (!staged[i].a) {
                pin_off(p);
                continue;
            }
            if (!p->on)
                act[n_act++] = p;
            start_train(p, &staged[i], t_next);
        }
    }
    if (commit || (any_on && (int32_t)(next_edge - t_next) <= 0))
        advance(t_next, (uint8_t)(k + 1));    /* (inline: one call's cost less per tick) */
    cli();
    uint8_t late = 0, wiped = off_count != offs;
    if (wiped) {
        all_pins_wiped();                     /* the watchdog fired meanwhile: it stands */
        commit = 0;
    } else {
        late = (uint8_t)((uint8_t)vt_ticks - (uint8_t)k);   /* ticks that came meanwhile */
        out_a = g_now[0];
        out_c = g_now[1];
        out_l = g_now[2];
        out_g = g_now[3];
    }
    pre_commit = commit;
    pre_sync = commit && vt_commit_onsets;
    preparing = PREPARED;                     /* a tick from now on finds its gates ready */
    if (!wiped) {
        /* What this preparation turned off is off in the gates it leaves: the ring and the
         * hold have nothing more to do for those pins. A pin at a time, interrupts on in
         * between: with 25 pins falling, the loop kept a tick waiting past a short
         * interrupt. A tick meanwhile only applies gates that have them off already. */
        for (uint8_t j = 0; j < n_fell; j++) {
            sei();                            /* (an interrupt waits one instruction more) */
            pin_t *p = fell[j];
            uint8_t m = (uint8_t)~p->mask;
            cli();
            fall_ring[p->fall_slot][p->port] &= m;
            held_off[p->port] &= m;
        }
    }
    if (commit && late) {
        /* The set goes out that many ticks late, and is reported then: its trains are
         * timed from then, and a first pulse keeps its whole width (its fall moves
         * too). No preparation runs meanwhile; a tick that would empty a fall's slot
         * first only ends that pulse sooner. */
        uint32_t late_us = (uint32_t)late * VT_TICK_US;
        sei();
        for (uint8_t j = 0; j < n_staged; j++) {
            pin_t *p = &pins[staged_list[j]];
            if (!p->on)
                continue;
            p->rise += late_us;
            p->until += late_us;              /* its end keeps its duration */
            if (p->fresh && p->high) {
                p->edge += late_us;
                cli();
                volatile uint8_t *slot = &fall_ring[p->fall_slot][p->port];
                if (*slot & p->mask) {
                    *slot &= (uint8_t)~p->mask;
                    p->fall_slot = (uint8_t)(p->fall_slot + late) & FALL_MASK;
                    fall_ring[p->fall_slot][p->port] |= p->mask;
                }
                sei();
            }
        }
        cli();
    }
    sei();
}

/* The preparations a tick asks for: the next tick's, and one more for each tick that came
 * meanwhile. Each runs with interrupts on, in a function of its own, so what runs with
 * them off after the last is only the returns (a tick that comes then waits for no more
 * than that). A set committed and not yet shown is never prepared twice: the tick that
 * shows it prepares the next. */
static void __attribute__((noinline)) prepare_ticks(void)
{
    for (;;) {
        preparing = PREPARING;
        prepare();
        cli();
        if (!prepare_again || pre_commit)
            break;
        prepare_again = 0;
    }
    prepare_again = 0;
    preparing = IDLE;
}

void vt_out_tick(void)
{
    /* the falls due at this tick, from the ring, whatever the preparation did */
    volatile uint8_t *f = fall_ring[(uint8_t)(*(volatile uint8_t *)&vt_ticks + 1) & FALL_MASK];
    uint8_t h0 = held_off[0] | f[0], h1 = held_off[1] | f[1], h2 = held_off[2] | f[2],
            h3 = held_off[3] | f[3];
    uint8_t pb = PORTB & (uint8_t)~_BV(SYNC_BIT);
    if (pre_sync)
        pb |= _BV(SYNC_BIT);
    gates(out_a & (uint8_t)~h0, out_c & (uint8_t)~h1, out_l & (uint8_t)~h2,
          out_g & (uint8_t)~h3);              /* the edges of this tick, in one instant */
    uint16_t c = TCNT1;                       /* when, in 0.5 us counts after the tick */
    PORTB = pb;
    held_off[0] = h0;
    held_off[1] = h1;
    held_off[2] = h2;
    held_off[3] = h3;
    f[0] = f[1] = f[2] = f[3] = 0;
    uint32_t k = vt_clock_tick();
    if (pre_commit) {
        pre_commit = 0;
        vt_commit_applied(c);
        if (n_dac_xfer) {
            /* The amplitudes of trains that replace a running one on their pin, in their
             * channels' input registers since the commit: updated after this tick's
             * edges (the first ~38 us of the new train's first pulse carry the old
             * amplitude), not before (that would touch the old train). A tick that comes
             * meanwhile finds the next not yet prepared: its edges go out a tick late
             * (the fall ring keeps its falls on time). */
            uint8_t n = n_dac_xfer;
            n_dac_xfer = 0;
            sei();
            dac_send(dac_xfer, n);
            cli();
            if (vt_ticks != k)
                return;                       /* a tick came meanwhile and did the rest */
        }
    }
    if (vt_deadline_armed && (int32_t)(k - vt_deadline_tick) >= 0) {
        gates(0, 0, 0, 0);                    /* the host is gone: every pin off now */
        vt_deadline_armed = 0;
        vt_out_event = 1;
        all_pins_off();
    }
    if (preparing) {
        /* The tick before is still preparing: this tick's preparation comes after it,
         * before that interrupt returns. If the gates for this tick were not ready, its
         * edges go out a tick late (the fall ring keeps falls on time). */
        if (preparing == PREPARING && vt_late_ticks != 0xFFFF)
            vt_late_ticks++;
        prepare_again = 1;
        return;
    }
    prepare_ticks();                          /* (a tail call: nothing to restore after it) */
}

void vt_hal_stage_begin(void)
{
    staged_mask = 0;
    n_staged = 0;
}

void vt_hal_stage(uint16_t index, const vt_setting *s)
{
    if (index >= N)
        return;
    staged_t *st = &staged[index];
    st->a = s->a;
    st->d = s->d;
    if (s->a) {                               /* 32-bit divisions: here, not in the tick */
        st->t.q = 100000000UL / s->f;
        st->t.r = (uint16_t)(100000000UL % s->f);
        st->t.f = s->f;
        st->t.w = s->w;
        uint16_t wt = (uint16_t)((s->w + VT_TICK_US - 1) / VT_TICK_US);
        st->t.wt = (uint8_t)wt;
        st->t.wrem = (uint8_t)(s->w - (wt - 1) * VT_TICK_US);
    }
    if (!(staged_mask & (1UL << index)))
        staged_list[n_staged++] = (uint8_t)index;
    staged_mask |= 1UL << index;
}

void vt_out_prepare(void) {}                  /* the tick interrupt prepares the next tick */

/* Before a set is scheduled (out_commit.c): the amplitudes it needs. The channels of
 * pins that are idle now are written and updated at once, out of the tick, where they
 * disturb no train; those of the rest are written to their input registers, and the
 * commit's tick updates them after its edges. The tick reads n_dac_xfer only once this
 * set is scheduled (the core commits one set at a time), so it is written here with
 * interrupts on. */
void vt_out_commit_prepare(void)
{
    uint32_t idle = 0, bit = 1;
    for (uint8_t i = 0; i < N; i++, bit <<= 1) {
        if (!(staged_mask & bit))
            continue;
        if (staged[i].a)
            dac_want[i] = code_of(staged[i].a);
        if (!pins[i].on)
            idle |= bit;
    }
    dac_update(idle, DAC_WRITE);
    n_dac_xfer = dac_plan_update(dac_update(staged_mask & ~idle, DAC_WRITE_INPUT));
}

void vt_hal_all_off(void)
{
    cli();
    gates(0, 0, 0, 0);                        /* off at once */
    vt_commit_abandon();
    pre_commit = 0;
    pre_sync = 0;
    uint8_t n = n_act;
    n_act = 0;                                /* the ticks have nothing to visit or drive */
    any_on = 0;
    out_a = out_c = out_l = out_g = 0;
    g_now[0] = g_now[1] = g_now[2] = g_now[3] = 0;   /* what a tick's preparation leaves */
    off_count++;
    sei();
    /* the pins forgotten with interrupts on, but for each one's slot in the ring (a tick
     * empties its slot: both must not write it at once) */
    for (uint8_t k = 0; k < n; k++) {
        pin_t *p = act[k];
        if (p->high) {
            cli();
            fall_ring[p->fall_slot][p->port] &= (uint8_t)~p->mask;
            sei();
        }
        p->on = p->high = 0;
    }
    cli();
    held_off[0] = held_off[1] = held_off[2] = held_off[3] = 0;
    sei();
    /* A set abandoned before its tick: the channels written to their input registers for
     * it are updated now, every pin being off, so that input and DAC registers agree
     * again (the tick no longer sends it: pre_commit is off). */
    if (n_dac_xfer) {
        uint8_t nx = n_dac_xfer;
        n_dac_xfer = 0;
        dac_send(dac_xfer, nx);
    }
}

#endif
