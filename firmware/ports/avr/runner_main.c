/* The vector runner on the ATmega2560, on its UART (tests/test_firmware.py drives it
 * in simavr through the harness's pty). Same runner, same core as the host's. */
#include <avr/interrupt.h>
#include <avr/sleep.h>

#include "avr_port.h"
#include "vt_runner.h"

int vt_runner_getc(void)
{
    while (!vt_uart_available()) {
        cli();
        if (!vt_uart_available()) {
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
    return vt_uart_get();
}

void vt_runner_putc(char c) { vt_uart_put((uint8_t)c); }

int main(void)
{
    vt_uart_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    for (const char *s = "vectors ready\n"; *s; s++)
        vt_uart_put((uint8_t)*s);             /* bytes sent before this would be lost */
    vt_runner_run();
    for (;;)
        ;
}
