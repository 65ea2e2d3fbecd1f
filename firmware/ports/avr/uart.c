/* UART0 at 1,000,000 baud (U2X, UBRR = 1, exact at 16 MHz), 8N1: a 256-byte receive
 * ring filled by the receive interrupt, and a 128-byte transmit ring drained by the
 * data-register-empty interrupt. */
#include <avr/interrupt.h>
#include <avr/io.h>

#include "avr_port.h"
#include "board.h"

volatile uint8_t vt_rx_ring[256];
volatile uint8_t vt_rx_head, vt_rx_tail;
static volatile uint8_t tx_ring[128];
static volatile uint8_t tx_head, tx_tail;
volatile uint16_t vt_uart_overruns;

void vt_uart_init(void)
{
    UCSR0A = _BV(U2X0);                       /* before UBRR0: simavr times bytes when UBRR0 is written */
    UBRR0 = (uint16_t)(F_CPU_HZ / (8 * VT_BAUD) - 1);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);       /* 8N1 */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART0_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t h = vt_rx_head;
    uint8_t n = (uint8_t)(h + 1);
    if (n == vt_rx_tail) {
        vt_uart_overruns++;
        return;
    }
    vt_rx_ring[h] = b;
    vt_rx_head = n;
}


ISR(USART0_UDRE_vect)
{
    uint8_t t = tx_tail;
    if (t == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_ring[t];
    tx_tail = (uint8_t)((t + 1) & 127);
}

void vt_uart_put(uint8_t byte)
{
    uint8_t h = tx_head;
    uint8_t n = (uint8_t)((h + 1) & 127);
    while (n == tx_tail)
        ;                                     /* full: the interrupt empties it */
    tx_ring[h] = byte;
    tx_head = n;
    UCSR0B |= _BV(UDRIE0);
}
