/* CRC-32/ISO-HDLC (IEEE 802.3, zlib): reflected 0x04C11DB7, init and xor-out
 * 0xFFFFFFFF; the check value of ASCII "123456789" is 0xCBF43926.
 *
 * Table-driven, one byte at a time: about 33 AVR cycles a byte with the table in
 * flash, against about 243 bit by bit, so that a frame can be checked as fast as
 * a 1 Mbaud UART delivers it (a byte every 160 cycles at 16 MHz).
 */
#ifndef VT_CRC32_H
#define VT_CRC32_H

#include <stddef.h>
#include <stdint.h>

#define VT_CRC_INIT 0xFFFFFFFFUL

uint32_t vt_crc32_update(uint32_t crc, uint8_t byte);
/* The CRC of a whole buffer (init and xor-out applied). */
uint32_t vt_crc32(const uint8_t *data, size_t n);

#endif
