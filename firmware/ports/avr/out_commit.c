/* Committing a staged set of outputs for a tick (see out_commit.h): the HAL's commit
 * functions, for either drive. */
#include <avr/interrupt.h>
#include <avr/io.h>

#include "avr_port.h"
#include "out_commit.h"
#include "vt_hal.h"
#include "vt_profile.h"

volatile uint8_t vt_commit_state, vt_commit_onsets;
volatile uint32_t vt_commit_tick;
volatile uint64_t vt_commit_t;

/* The earliest tick a set committed now can go out at (interrupts off). */
static uint32_t earliest_tick(void)
{
    uint32_t k = vt_ticks;
#if VT_PREPARE_AT
    /* Prepared at compare B: the next tick, unless its compare B has been served. */
    if (TIFR1 & _BV(OCF1A))
        return k + 2;                         /* tick k + 1 began; its compare B is to come */
    if (TCNT1 < OCR1B || (TIFR1 & _BV(OCF1B)))
        return k + 1;                         /* the next tick's outputs are not prepared yet */
#endif
    return k + 2;                             /* the next tick's outputs are prepared already */
}

/* The tick a set for time t goes out at: the first at or after t, and not before the
 * earliest. */
static uint32_t commit_tick_for(uint64_t t_us)
{
    uint32_t k = vt_clock_tick_for(t_us);
    uint8_t sreg = SREG;
    cli();
    uint32_t earliest = earliest_tick();
    SREG = sreg;
    return (int32_t)(k - earliest) < 0 ? earliest : k;
}

uint64_t vt_hal_commit_time(uint64_t t_us) { return vt_clock_tick_time(commit_tick_for(t_us)); }

void vt_hal_commit_at(uint64_t t_us, uint8_t onsets)
{
    uint32_t k = commit_tick_for(t_us);
    vt_out_commit_prepare();
    cli();
    uint32_t earliest = earliest_tick();      /* time has passed since: check again */
    if ((int32_t)(k - earliest) < 0)
        k = earliest;
    vt_commit_tick = k;
    vt_commit_onsets = onsets;
    vt_commit_state = VT_COMMIT_SCHEDULED;
    sei();
}

uint8_t vt_hal_committed(uint64_t *t_us)
{
    uint8_t done = 0;
    cli();
    if (vt_commit_state == VT_COMMIT_DONE) {
        *t_us = vt_commit_t;
        vt_commit_state = VT_COMMIT_NONE;
        done = 1;
    }
    sei();
    return done;
}

uint64_t vt_hal_commit_now(void)
{
    uint64_t t;
    vt_hal_commit_at(0, 1);                   /* as onsets: a carrier restarts, sync rises */
    while (!vt_hal_committed(&t))
        ;                                     /* at most two ticks */
    return t;
}

/* A play starts on a tick at least VT_START_LEAD_US away, so that its first instant,
 * prepared after the trigger is answered, makes it. */
uint64_t vt_hal_align_start(uint64_t t_us)
{
    uint64_t soonest = vt_hal_now_us() + VT_START_LEAD_US;
    return vt_hal_commit_time(t_us > soonest ? t_us : soonest);
}
