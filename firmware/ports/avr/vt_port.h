/* The AVR port: the CRC table stays in flash. */
#ifndef VT_PORT_H
#define VT_PORT_H

#include <avr/pgmspace.h>

#define VT_TABLE_ATTR PROGMEM
#define VT_TABLE_READ32(p) pgm_read_dword(p)

#endif
