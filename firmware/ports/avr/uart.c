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

/* A byte received: into the ring at its head, which is always free (the ring keeps one
 * place empty), and the head moves on unless the ring is full (the byte is then dropped
 * and counted). The same as
 *
 *     uint8_t h = vt_rx_head, n = h + 1;
 *     vt_rx_ring[h] = UDR0;
 *     if (n == vt_rx_tail) vt_uart_overruns++; else vt_rx_head = n;
 *
 * in assembly: the compiler's version saves nine registers and takes about 70 cycles; at
 * 1 Mbaud a byte comes every 160, and a frame's bytes nest in the tick interrupt's
 * preparation (out_trains.c), whose time they add to. This one takes about 45. */
ISR(USART0_RX_vect, ISR_NAKED)
{
    __asm__ __volatile__(
        "push r24\n\t"
        "in r24, __SREG__\n\t"
        "push r24\n\t"
        "push r30\n\t"
        "push r31\n\t"
        "lds r30, vt_rx_head\n\t"
        "ldi r31, 0\n\t"
        "subi r30, lo8(-(vt_rx_ring))\n\t"
        "sbci r31, hi8(-(vt_rx_ring))\n\t"
        "lds r24, %[udr]\n\t"
        "st Z, r24\n\t"
        "lds r30, vt_rx_head\n\t"
        "inc r30\n\t"
        "lds r24, vt_rx_tail\n\t"
        "cp r30, r24\n\t"
        "breq 1f\n\t"
        "sts vt_rx_head, r30\n\t"
        "rjmp 2f\n"
        "1:\n\t"
        "lds r30, vt_uart_overruns\n\t"
        "lds r31, vt_uart_overruns+1\n\t"
        "adiw r30, 1\n\t"
        "sts vt_uart_overruns+1, r31\n\t"
        "sts vt_uart_overruns, r30\n"
        "2:\n\t"
        "pop r31\n\t"
        "pop r30\n\t"
        "pop r24\n\t"
        "out __SREG__, r24\n\t"
        "pop r24\n\t"
        "reti\n\t"
        :: [udr] "n"(_SFR_MEM_ADDR(UDR0)));
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
