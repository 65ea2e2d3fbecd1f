/* The portable core of the vtexp reference firmware: wire protocol v1, device side.
 *
 * It knows nothing of the chip. Bytes from the host go in with vt_rx_byte(); the
 * main loop calls vt_poll() as often as it can (it plays the schedule and checks
 * the watchdog); everything the device sends leaves through vt_hal_tx(), and
 * outputs change only through the vt_hal_stage()/commit functions (vt_hal.h).
 *
 * Behaviour is docs/protocol.md's, and protocols/wire/v1_vectors.json pins it
 * byte for byte (tests/test_firmware.py runs the vectors on the host build and,
 * in simavr, on the ATmega2560 build).
 *
 * Storage is static and sized at compile time (vt_profile.h): a schedule of
 * VT_MAX_PULSES pulses, a receive buffer of VT_MAX_PAYLOAD + 7 bytes, counters for
 * VT_MAX_ACTUATORS actuators.
 */
#ifndef VT_CORE_H
#define VT_CORE_H

#include <stdint.h>

/* One actuator's setting in wire units. Level drive: a = level, f = w = 0.
 * Pulse trains: a = amplitude in mV (0 = off), f = frequency in 0.01 Hz, w = pulse
 * width in us. d: for how long it holds from the instant it is staged at, in us, as
 * the schedule says (the rest of its pulse); 0 for a frame, which holds until changed.
 * A train port starts no pulse at or after that end, even if the set that turns the
 * actuator off comes late (docs/protocol.md, "What a pulse train is"). */
typedef struct {
    uint16_t a, f, w;
    uint32_t d;
} vt_setting;

/* What the device is and holds; reported in HELLO_REPLY. */
typedef struct {
    uint16_t rows, cols;
    uint8_t actuator, drive, max_level;
    uint16_t max_amplitude_mv, max_frequency_chz, max_width_us;
    uint16_t max_pulses, max_payload;
    uint16_t min_watchdog_ms, max_watchdog_ms;
    const char *firmware, *device_id;
} vt_config;

/* Counters, as STATUS_REPLY reports them. */
typedef struct {
    uint32_t rx_frames, rx_bad, duplicates;
    uint16_t watchdog_trips;
} vt_counters;

/* Start (or restart, as at power-on) with this configuration: no session, every
 * output off. The configuration must outlive the core. */
void vt_init(const vt_config *cfg);

/* One byte from the host. A completed frame is executed at once and answered
 * through vt_hal_tx(). */
void vt_rx_byte(uint8_t b);

/* Do what is due: the watchdog, then the schedule. Call it from the main loop, and
 * before each received byte's frame is executed (vt_rx_byte does). */
void vt_poll(void);

/* The device time at which vt_poll() has something to do next (VT_NEVER if nothing:
 * no session and no play), so that a port may sleep until then or until a byte. */
#define VT_NEVER UINT64_MAX
uint64_t vt_next_deadline_us(void);

/* Send one frame of any type, sequence number and payload, through vt_hal_tx(): the
 * core's own encoder (COBS, CRC-32, delimiters), for tests and tools. */
void vt_send_frame(uint8_t type, uint8_t seq, const uint8_t *payload, uint16_t n);

const vt_counters *vt_get_counters(void);
uint8_t vt_state(void);

#endif
