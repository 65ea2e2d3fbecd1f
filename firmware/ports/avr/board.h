/* Arduino Mega 2560 (ATmega2560, 16 MHz): what goes on which pin (docs/firmware.md,
 * "Wiring"). Pins are named PORTx bit (Arduino pin). */
#ifndef VT_BOARD_H
#define VT_BOARD_H

#include <avr/io.h>

#define F_CPU_HZ 16000000UL
#define VT_BAUD 1000000UL           /* U2X, UBRR = 1: exact at 16 MHz */

/* SPI master: PB0 SS (D53, kept an output), PB1 SCK (D52), PB2 MOSI (D51), PB3 MISO (D50) */
#define SPI_DDR DDRB
#define SPI_SS PB0
#define SPI_SCK PB1
#define SPI_MOSI PB2

/* The chain's latch: TPIC6B595 RCK (levels), LTC2656 CS/LD (pulse trains): PB4 (D10) */
#define LATCH_PORT PORTB
#define LATCH_BIT PB4
/* TPIC6B595 /G, output enable, active low: PB5 (D11), 10 kOhm pull-up to 5 V so that the
 * outputs stay off through reset and programming */
#define OE_PORT PORTB
#define OE_BIT PB5
/* TTL sync out to an EEG amplifier's trigger input: PB6 (D12), high for one output tick at each onset instant (1 ms for levels, 100 us for trains) */
#define SYNC_PORT PORTB
#define SYNC_BIT PB6

/* SMA pins (pulse trains): logic-level MOSFET gates on whole ports, 10 kOhm pull-downs;
 * actuator 0-7 on PA0-7 (D22-D29), 8-15 on PC0-7 (D37-D30), 16-23 on PL0-7 (D49-D42),
 * 24 on PG0 (D41). */

#endif
