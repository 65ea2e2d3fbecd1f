/* vtexp reference firmware, ATmega2560 (Arduino Mega 2560): the main loop.
 *
 * Start-up turns every output off before anything else (also through reset: the
 * TPIC6B595s' output enable has a pull-up, the SMA gates pull-downs), then runs the
 * core: received bytes in, vt_poll(), and sleep (idle mode) until the next
 * interrupt. The hardware watchdog (120 ms) restarts a firmware that hangs; the
 * protocol's watchdog (vt_hal_set_deadline) turns the outputs off when the host
 * goes silent, from the tick interrupt, whatever the main loop is doing.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "avr_port.h"
#include "board.h"
#include "vt_core.h"
#include "vt_hal.h"
#include "vt_profile.h"

#ifndef VT_FW_VERSION
#define VT_FW_VERSION "dev"
#endif
#ifndef VT_DEVICE_ID
#define VT_DEVICE_ID "atmega2560 " VT_PROFILE_NAME
#endif

static const vt_config config = {
    .rows = VT_ROWS, .cols = VT_COLS, .actuator = VT_ACTUATOR, .drive = VT_DRIVE,
    .max_level = VT_MAX_LEVEL, .max_amplitude_mv = VT_MAX_AMPLITUDE_MV,
    .max_frequency_chz = VT_MAX_FREQUENCY_CHZ, .max_width_us = VT_MAX_WIDTH_US,
    .max_pulses = VT_MAX_PULSES, .max_payload = VT_MAX_PAYLOAD,
    .min_watchdog_ms = 20, .max_watchdog_ms = 10000,
    .firmware = "vtexp-fw " VT_FW_VERSION " avr " VT_PROFILE_NAME,
    .device_id = VT_DEVICE_ID,
};

/* Before C start-up: outputs off, and the watchdog that may have reset us stopped. */
void vt_early(void) __attribute__((naked, used, section(".init3")));
void vt_early(void)
{
    MCUSR = 0;
    wdt_disable();
    vt_out_safe();
}

void vt_hal_tx(uint8_t byte) { vt_uart_put(byte); }

volatile uint8_t vt_deadline_armed;
volatile uint32_t vt_deadline_tick;

void vt_hal_set_deadline(uint64_t t_us)
{
    /* off at the first tick after the deadline */
    uint32_t k = t_us == VT_NO_DEADLINE ? 0 : vt_clock_tick_for(t_us + 1);
    uint8_t sreg = SREG;
    cli();
    vt_deadline_tick = k;
    vt_deadline_armed = t_us != VT_NO_DEADLINE;
    SREG = sreg;
}

ISR(TIMER1_COMPA_vect)
{
    vt_out_tick();
}

ISR(TIMER1_COMPB_vect)
{
    vt_out_prepare();
}

int main(void)
{
    vt_out_init();
    vt_clock_init(VT_TICK_US, VT_PREPARE_AT);
    vt_uart_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    wdt_enable(WDTO_120MS);
    sei();
    vt_init(&config);
    uint32_t poll_tick = 0;
    for (;;) {
        wdt_reset();
        uint8_t work = vt_out_event;
        while (vt_uart_available()) {
            uint8_t b = vt_uart_get();
            vt_rx_byte(b);
            work |= b == 0;                   /* a frame ended: it may have started a play */
        }
        /* The core is polled when a frame ended, when the outputs did something, or when
         * it said it has something due; not at every byte (at 1 Mbaud a byte comes every
         * 176 cycles) nor every tick (15 % of the CPU at 10 kHz). */
        if (work || (int32_t)(vt_ticks - poll_tick) >= 0) {
            vt_out_event = 0;
            vt_poll();
            uint64_t due = vt_next_deadline_us();
            poll_tick = due == VT_NEVER ? vt_ticks + 0x10000000UL : vt_clock_tick_for(due);
        }
        cli();
        if (!vt_uart_available() && !vt_out_event) {
            sleep_enable();
            sei();                            /* sei then sleep: no wake-up is missed */
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
