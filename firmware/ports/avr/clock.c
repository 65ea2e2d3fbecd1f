/* The ATmega2560's clock for the vtexp firmware.
 *
 * Timer1 in CTC mode counts 0.5 us (16 MHz / 8) and interrupts every tick
 * (1 ms for level drives, 100 us for pulse trains). Its compare register is written
 * once, at start-up: the tick never drifts against the crystal (rewriting it is what
 * makes simulated AVR timers drift, simavr issue 169).
 */
#include <avr/interrupt.h>
#include <avr/io.h>

#include "avr_port.h"
#include "board.h"
#include "vt_hal.h"
#include "vt_profile.h"

volatile uint32_t vt_ticks;
volatile uint32_t vt_tick_us_lo, vt_tick_us_hi; /* the time of tick vt_ticks, us, in halves:
                                                 * 32-bit additions are cheap in an interrupt */
volatile uint8_t vt_out_event;

/* Interrupts are off only while the tick's words are copied (a few cycles): a tick
 * interrupt that waits for a 64-bit computation here would raise its edges late. */

void vt_clock_init(uint16_t tick_us, uint16_t prepare_at)
{
    TCCR1A = 0;
    TCCR1B = 0;
    TCNT1 = 0;
    OCR1A = (uint16_t)(2 * tick_us - 1);
    OCR1B = prepare_at;                       /* written once, like OCR1A */
    TIFR1 = _BV(OCF1A) | _BV(OCF1B);
    TIMSK1 = _BV(OCIE1A) | (prepare_at ? _BV(OCIE1B) : 0);
    TCCR1B = _BV(WGM12) | _BV(CS11);          /* CTC on OCR1A, clk/8 */
}

uint64_t vt_hal_now_us(void)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t lo = vt_tick_us_lo, hi = vt_tick_us_hi;
    uint16_t c = TCNT1;
    /* the counter has wrapped but the tick interrupt has not run yet */
    uint8_t wrapped = (TIFR1 & _BV(OCF1A)) && c < VT_TICK_US;
    SREG = sreg;
    uint64_t t = vt_us64(hi, lo);
    if (wrapped)
        t += VT_TICK_US;
    return t + (c >> 1);
}

/* The current tick and its time, copied with interrupts off. Inlined into each caller,
 * which then compiles as it did with the copy written out in it. */
static inline __attribute__((always_inline)) uint32_t tick_now(uint64_t *base)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t k = vt_ticks, lo = vt_tick_us_lo, hi = vt_tick_us_hi;
    SREG = sreg;
    *base = vt_us64(hi, lo);
    return k;
}

/* No 64-bit division here: it costs thousands of cycles on an AVR. Times are turned into
 * ticks from the current tick, in 32 bits. */
uint32_t vt_clock_tick_for(uint64_t t_us)
{
    uint64_t base;
    uint32_t k = tick_now(&base);
    if (t_us <= base)
        return k;
    uint64_t d = t_us - base;
    if (d > 0x7FFFFFFFUL)
        return k + 0x7FFFFFFFUL / VT_TICK_US;     /* half an hour or more ahead */
    if (d <= 0xFFFFU - VT_TICK_US)                /* the usual case: 16-bit division */
        return k + ((uint16_t)d + VT_TICK_US - 1) / VT_TICK_US;
    return k + ((uint32_t)d + VT_TICK_US - 1) / VT_TICK_US;
}

uint64_t vt_clock_tick_time(uint32_t k)
{
    uint64_t base;
    uint32_t now = tick_now(&base);
    int32_t d = (int32_t)(k - now);
    return d >= 0 ? base + (uint32_t)d * VT_TICK_US : base - (uint32_t)(-d) * VT_TICK_US;
}

