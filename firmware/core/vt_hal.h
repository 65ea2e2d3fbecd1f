/* What a port provides to the core: the chip-specific half of the firmware.
 *
 * To put the core on another chip, write these functions (docs/firmware.md,
 * "Porting the core"). The core calls them from its main loop only, never from
 * an interrupt. Times are microseconds of the device clock since power-on.
 */
#ifndef VT_HAL_H
#define VT_HAL_H

#include <stdint.h>
#include "vt_core.h"

/* The device clock, microseconds since power-on. Never goes backwards. */
uint64_t vt_hal_now_us(void);

/* Send one byte to the host. May block until there is room; must not drop it. */
void vt_hal_tx(uint8_t byte);

/* Outputs are changed in sets: vt_hal_stage_begin() starts a set from the outputs
 * as they are (or as the last committed set left them), vt_hal_stage() changes one
 * actuator in it, and a commit applies the whole set in one instant. */
void vt_hal_stage_begin(void);
void vt_hal_stage(uint16_t index, const vt_setting *s);

/* Apply the staged set as soon as the outputs can change; return the device time
 * at which they changed (read after the change). May block up to one output tick. */
uint64_t vt_hal_commit_now(void);

/* The time at which a set committed for time t would take effect: t itself, or the
 * first tick of the output clock at or after t, and never before the earliest time
 * the port can still make. */
uint64_t vt_hal_commit_time(uint64_t t_us);

/* Apply the staged set at vt_hal_commit_time(t_us), without waiting. onsets != 0
 * says that pulses start in it (the port may re-phase a carrier so that every onset
 * starts a full period, and raises its sync output). */
void vt_hal_commit_at(uint64_t t_us, uint8_t onsets);

/* Nonzero once the last vt_hal_commit_at() set has been applied; *t_us then holds
 * the device time read right after the outputs changed. */
uint8_t vt_hal_committed(uint64_t *t_us);

/* Every output off at once; a staged or scheduled set is abandoned. */
void vt_hal_all_off(void);

/* The start of a play asked to start at t_us (at least t_us): a port may align it to
 * its output clock, by less than 5 ms (docs/protocol.md, TRIGGER). */
uint64_t vt_hal_align_start(uint64_t t_us);

/* The watchdog deadline: after device time t_us with no valid request, every output
 * must be off. A port should enforce it from a timer interrupt (the core also checks
 * it in its loop, and does the protocol's part: PLAY_DONE, ALARM, end of session).
 * VT_NO_DEADLINE: no session, no deadline. */
#define VT_NO_DEADLINE UINT64_MAX
void vt_hal_set_deadline(uint64_t t_us);

#endif
