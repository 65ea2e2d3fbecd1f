/* Wire protocol v1: the numbers on the wire (docs/protocol.md, "Messages").
 *
 * Nothing here depends on a chip; every multi-byte field on the wire is
 * little-endian, which the core reads and writes byte by byte so that it works
 * on any CPU.
 */
#ifndef VT_WIRE_H
#define VT_WIRE_H

#include <stdint.h>

#define VT_PROTOCOL 1          /* the protocol and frame version this firmware speaks */
#define VT_MIN_FRAME 7         /* version, type, seq, CRC-32: a frame with no payload */

/* Requests (host -> device). */
enum {
    VT_HELLO = 0x01, VT_HEARTBEAT = 0x02, VT_ALL_OFF = 0x03, VT_SET_FRAME = 0x04,
    VT_SET_FRAME_FULL = 0x05, VT_UPLOAD_BEGIN = 0x06, VT_UPLOAD_CHUNK = 0x07,
    VT_TRIGGER = 0x08, VT_STATUS = 0x09, VT_GET_ONSETS = 0x0A, VT_BYE = 0x0B
};
/* Replies and events (device -> host). */
enum {
    VT_HELLO_REPLY = 0x41, VT_ACK = 0x42, VT_NAK = 0x43, VT_STATUS_REPLY = 0x44,
    VT_ONSETS_REPLY = 0x45, VT_ONSET = 0x61, VT_PLAY_DONE = 0x62, VT_ALARM = 0x63
};
/* NAK reasons. */
enum {
    VT_NAK_BAD_FRAME = 1, VT_NAK_BAD_VERSION = 2, VT_NAK_UNKNOWN_TYPE = 3,
    VT_NAK_BAD_PAYLOAD = 4, VT_NAK_NO_SESSION = 5, VT_NAK_UNSUPPORTED_PROTOCOL = 6,
    VT_NAK_OUT_OF_RANGE = 7, VT_NAK_WRONG_DRIVE = 8, VT_NAK_BUSY = 9,
    VT_NAK_NO_SCHEDULE = 10, VT_NAK_OUT_OF_ORDER = 11, VT_NAK_TOO_LARGE = 12
};
/* Device states (STATUS_REPLY). */
enum { VT_IDLE = 0, VT_UPLOADING = 1, VT_ARMED = 2, VT_PLAYING = 3, VT_NO_SESSION = 4 };
/* PLAY_DONE reasons and ALARM codes. */
enum { VT_DONE_FINISHED = 0, VT_DONE_ALL_OFF = 1, VT_DONE_WATCHDOG = 2 };
enum { VT_ALARM_WATCHDOG = 1 };
/* Actuator kinds and drive kinds (macros: build options test them in #if). */
#define VT_ERM_MOTOR 1
#define VT_COIN_TACTOR 2
#define VT_SMA_PIN 3
#define VT_DRIVE_LEVEL 1
#define VT_DRIVE_TRAIN 2

#define VT_NOT_PLAYED_U32 0xFFFFFFFFUL   /* an onset not (yet) played, kept relative */

#endif
