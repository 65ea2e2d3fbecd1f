/* What the AVR port's files share: the tick clock, the UART and the outputs. */
#ifndef VT_AVR_PORT_H
#define VT_AVR_PORT_H

#include <stdint.h>

#include "vt_profile.h"

/* ---- clock (clock.c): Timer1, CTC, 0.5 us counts; a tick every VT_TICK_US */
extern volatile uint32_t vt_ticks;
extern volatile uint32_t vt_tick_us_lo, vt_tick_us_hi;  /* the time of tick vt_ticks, us */
/* Set by the tick interrupt when the core has something to see (a set applied, the
 * watchdog fired): the main loop then calls vt_poll() at once. */
extern volatile uint8_t vt_out_event;
/* prepare_at: Timer1 counts into each tick at which vt_out_prepare() runs (0: never). */
void vt_clock_init(uint16_t tick_us, uint16_t prepare_at);
/* The first tick at or after t; the time of tick k (both near now). */
uint32_t vt_clock_tick_for(uint64_t t_us);
uint64_t vt_clock_tick_time(uint32_t k);
/* Called by the tick interrupt first: one more tick. */
#ifndef VT_RUNNER
static inline uint32_t vt_clock_tick(void)
{
    uint32_t lo = vt_tick_us_lo + VT_TICK_US;
    vt_tick_us_lo = lo;
    if (lo < VT_TICK_US)
        vt_tick_us_hi++;
    return ++vt_ticks;
}

#endif

/* Two 32-bit halves as one 64-bit time, without a shift: avr-gcc calls __ashldi3 for
 * `(uint64_t)hi << 32`, a loop of ~130 cycles, which must not run with interrupts off. */
static inline uint64_t vt_us64(uint32_t hi, uint32_t lo)
{
    union {
        uint64_t v;
        uint32_t w[2];                        /* little-endian: w[0] is the low half */
    } u;
    u.w[0] = lo;
    u.w[1] = hi;
    return u.v;
}

#ifndef VT_RUNNER
/* In the tick interrupt, after vt_clock_tick(): the time at which Timer1 read c. */
static inline uint64_t vt_clock_now_at(uint16_t c)
{
    return vt_us64(vt_tick_us_hi, vt_tick_us_lo) + (c >> 1);
}
#endif

/* ---- UART0 at 1 Mbaud (uart.c): interrupt-driven rings */
void vt_uart_init(void);
extern volatile uint8_t vt_rx_ring[256];
extern volatile uint8_t vt_rx_head, vt_rx_tail;
/* Inline: at 1 Mbaud a byte comes every 160 cycles, calls cost too much per byte. */
static inline uint8_t vt_uart_available(void) { return vt_rx_head != vt_rx_tail; }
static inline uint8_t vt_uart_get(void)
{
    uint8_t t = vt_rx_tail;
    uint8_t b = vt_rx_ring[t];
    vt_rx_tail = (uint8_t)(t + 1);
    return b;
}
/* Queue a byte to send; waits while the transmit ring is full. */
void vt_uart_put(uint8_t byte);
/* bytes that arrived while the receive ring was full (a host that does not wait) */
extern volatile uint16_t vt_uart_overruns;

/* ---- outputs (out_levels.c or out_trains.c) */
/* Every output off, ports set up: the first thing after reset (also from .init3). */
void vt_out_safe(void);
void vt_out_init(void);
/* Called first thing by the tick interrupt: latch the outputs prepared at the last
 * tick. Then the port's own work, with interrupts enabled again. */
void vt_out_tick(void);
/* Called by Timer1's compare B, if the port asked for it: prepare the next tick. */
void vt_out_prepare(void);

/* ---- the watchdog deadline (main.c), checked by the tick interrupt */
extern volatile uint8_t vt_deadline_armed;
extern volatile uint32_t vt_deadline_tick;

#endif
