/* Level drives (ERM motors, coin tactors): TPIC6B595 power shift registers on SPI,
 * software PWM.
 *
 * A 1 kHz tick and 10 slots make the 100 Hz carrier of seed 000 (Table 1): a motor
 * at level L is on during the first VT_LEVEL_SLOTS[L] slots of each period (duty
 * L/10 on the pad; 20 % and 60 % of a 5 V supply for the vest's 1 V and 3 V). The
 * outputs for each slot are kept as bit planes, one bit per actuator, in the chain's
 * byte order, so a tick only shifts one plane out.
 *
 * Timing: at each tick the interrupt pulses RCK, which latches the plane shifted out
 * during the previous tick, so every output change happens at the tick itself (a few
 * cycles after it); 85 % into the tick, Timer1's compare B shifts out the plane for the
 * next tick. A set of changes (vt_hal_stage) is prepared in the second set of planes
 * and committed for a tick (out_commit.c); the compare B before it shifts from the new
 * set. A set with onsets restarts the carrier at slot 0 (so each onset starts a whole
 * period, and the onset is the latch edge) and raises the sync output with the latch.
 *
 * Chain: MOSI -> chip 0 -> chip 1 -> ... Actuator i is bit i % 8 of chip i / 8
 * (DRAIN0..7); the byte for the farthest chip is shifted first, MSB first.
 */
#include "vt_profile.h"

#if VT_DRIVE == VT_DRIVE_LEVEL

#include <avr/interrupt.h>
#include <avr/io.h>
#include <string.h>

#include "avr_port.h"
#include "board.h"
#include "out_commit.h"
#include "vt_hal.h"

#define SLOTS 10
#define NB VT_CHAIN_BYTES

static const uint8_t level_slots[] = VT_LEVEL_SLOTS;
static uint8_t planes[2][SLOTS][NB];

static volatile uint8_t active;              /* the set being shown */
static volatile uint8_t slot;                /* carrier slot of the plane latched last */
static volatile uint8_t pre_pending;         /* the plane shifted out is the staged set's */
static volatile uint8_t pre_slot, pre_sync;

static volatile uint8_t oe_hold;             /* ticks before output enable comes back */

_Static_assert(sizeof planes <= VT_PORT_RAM_BYTES - 256 - 128 - 64,
               "profile " VT_PROFILE_NAME ": the PWM planes exceed the port's RAM budget");

static void oe_off(void) { OE_PORT |= _BV(OE_BIT); }
static void oe_on(void) { OE_PORT &= (uint8_t)~_BV(OE_BIT); }

void vt_out_safe(void)
{
    OE_PORT |= _BV(OE_BIT);                   /* /G high: drains off (the pull-up already is) */
    DDRB |= _BV(OE_BIT);
}

void vt_out_init(void)
{
    vt_out_safe();
    LATCH_PORT &= (uint8_t)~_BV(LATCH_BIT);
    SYNC_PORT &= (uint8_t)~_BV(SYNC_BIT);
    DDRB |= _BV(LATCH_BIT) | _BV(SYNC_BIT) | _BV(SPI_SS) | _BV(SPI_SCK) | _BV(SPI_MOSI);
    SPCR = _BV(SPE) | _BV(MSTR);              /* mode 0, MSB first */
    SPSR = _BV(SPI2X);                        /* fosc / 2 = 8 MHz */
    memset(planes, 0, sizeof planes);
    /* clear the chain, latch zeros, then let the drains follow it */
    for (uint8_t c = 0; c < NB; c++) {
        SPDR = 0;
        while (!(SPSR & _BV(SPIF)))
            ;
    }
    LATCH_PORT |= _BV(LATCH_BIT);
    LATCH_PORT &= (uint8_t)~_BV(LATCH_BIT);
    oe_on();
}

static inline void shift_out(const uint8_t *plane)
{
    for (int16_t c = NB - 1; c >= 0; c--) {
        SPDR = plane[c];
        while (!(SPSR & _BV(SPIF)))
            ;
    }
}

void vt_out_tick(void)
{
    /* 1. The outputs change: latch, and the sync edge in the same write. */
    uint8_t pb = PORTB & (uint8_t)~_BV(SYNC_BIT);
    if (pre_sync)
        pb |= _BV(SYNC_BIT);
    PORTB = pb | _BV(LATCH_BIT);
    uint16_t c = TCNT1;                       /* the latch edge, 0.5 us counts after the tick */
    PORTB = pb;
    uint32_t k = vt_clock_tick();
    slot = pre_slot;
    if (pre_pending) {                        /* a committed set is now on the outputs */
        active ^= 1;
        pre_pending = 0;
        vt_commit_applied(c);
    }
    /* 2. The protocol watchdog, here so that a busy main loop cannot delay it. */
    if (vt_deadline_armed && (int32_t)(k - vt_deadline_tick) >= 0) {
        oe_off();
        vt_deadline_armed = 0;
        vt_out_event = 1;
        oe_hold = 0xFF;                       /* until the core has cleared the planes */
    }
    if (oe_hold && oe_hold != 0xFF && --oe_hold == 0)
        oe_on();
}

/* Timer1 compare B, 85 % into each tick: shift out the plane for the next tick. Late in
 * the tick, so that a set committed up to then still makes the next tick (instants 1 ms
 * apart are both on time); the UART may interrupt it, and it is done (about 80 us for
 * 50 bytes) well before the next latch. */
void vt_out_prepare(void)
{
    uint32_t k = vt_ticks;
    sei();
    uint8_t use = vt_commit_due(k);
    uint8_t next = (use && vt_commit_onsets) ? 0 : (uint8_t)(slot + 1 == SLOTS ? 0 : slot + 1);
    shift_out(planes[use ? active ^ 1 : active][next]);
    cli();
    pre_slot = next;
    pre_pending = use;
    pre_sync = use && vt_commit_onsets;
}

void vt_hal_stage_begin(void)
{
    memcpy(planes[active ^ 1], planes[active], sizeof planes[0]);
}

void vt_hal_stage(uint16_t index, const vt_setting *s)
{
    uint8_t (*p)[NB] = planes[active ^ 1];
    uint8_t byte = (uint8_t)(index >> 3), mask = (uint8_t)(1 << (index & 7));
    uint8_t on = s->a < sizeof level_slots ? level_slots[s->a] : 0;
    for (uint8_t k = 0; k < SLOTS; k++) {
        if (k < on)
            p[k][byte] |= mask;
        else
            p[k][byte] &= (uint8_t)~mask;
    }
}

/* The planes hold the whole set: nothing to do before it is scheduled. */
void vt_out_commit_prepare(void) {}

void vt_hal_all_off(void)
{
    cli();
    oe_off();                                 /* off at once */
    vt_commit_abandon();
    pre_pending = 0;
    pre_sync = 0;
    oe_hold = 3;                              /* back on once zeros are latched */
    sei();
    memset(planes, 0, sizeof planes);
}

#endif
