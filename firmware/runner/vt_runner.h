/* The vector runner: replays protocols/wire/v1_vectors.json against the core with a
 * fake clock, driven line by line by tests/test_firmware.py. The same source runs
 * on the host (stdin/stdout) and on the ATmega2560 in simavr (its UART), so both
 * builds are held to the same bytes.
 *
 * Commands (one per line; hex without spaces; "-" for nothing), and their answers:
 *   config ROWS COLS ACTUATOR DRIVE MAX_LEVEL MAX_MV MAX_CHZ MAX_US MAX_PULSES
 *          MAX_PAYLOAD MIN_WD MAX_WD FIRMWARE_HEX DEVICE_ID_HEX     -> ok
 *   at T_US HEX      bytes from the host at device time T_US      -> = DEVICE_HEX
 *   tick T_US        the clock advances, nothing received           -> = DEVICE_HEX
 *   crc HEX          CRC-32 of the bytes                            -> = 8 hex digits
 *   cobs HEX         COBS-encode (no delimiters)                    -> = HEX
 *   uncobs HEX       COBS-decode                                    -> = HEX | ! bad | ! too_long
 *   frame TYPE SEQ HEX   the core's encoder (decimal TYPE, SEQ)     -> = HEX
 *   outputs          the actuators on (host build only)             -> = I:A,F,W ...
 * The port supplies vt_runner_getc() (-1 at the end of input) and vt_runner_putc().
 */
#ifndef VT_RUNNER_H
#define VT_RUNNER_H

int vt_runner_getc(void);
void vt_runner_putc(char c);
/* Serve commands until the input ends. */
void vt_runner_run(void);

#endif
