/* The host (POSIX) port: tables live in ordinary memory. */
#ifndef VT_PORT_H
#define VT_PORT_H

#define VT_TABLE_ATTR
#define VT_TABLE_READ32(p) (*(p))

#endif
