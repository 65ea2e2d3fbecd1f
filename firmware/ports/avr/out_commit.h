/* Committing a staged set of outputs for a tick: what the level drive (out_levels.c)
 * and the pulse trains (out_trains.c) share (out_commit.c).
 *
 * The core stages a set (vt_hal_stage) and commits it for a time (vt_hal_commit_at).
 * The commit is scheduled for the first tick at or after that time that the outputs
 * can still make; the preparation of that tick takes the set (vt_commit_due), and the
 * tick that shows it reports it (vt_commit_applied) with the time read right after the
 * outputs changed, which the core collects with vt_hal_committed. One set is committed
 * at a time: the core commits the next once the last is reported.
 *
 * The earliest tick a set can make depends on when the next tick is prepared: 85 %
 * into the tick, at Timer1's compare B, for the level drive (VT_PREPARE_AT), so a set
 * committed before then makes the next tick; by the tick interrupt itself for the
 * trains (VT_PREPARE_AT 0), so the next tick is always prepared already.
 *
 * The drive's hook, chosen at link time (a build has one drive), not a function pointer:
 *   vt_out_commit_prepare()  called by vt_hal_commit_at before it schedules the set,
 *                            interrupts on: what the drive must do ahead of the tick
 *                            (the trains write the amplitudes of idle pins now and plan
 *                            those of busy ones for the tick).
 * The parts the tick interrupt runs are inline here, so they cost the interrupt what
 * they cost when each drive wrote them out.
 */
#ifndef VT_OUT_COMMIT_H
#define VT_OUT_COMMIT_H

#include <stdint.h>

#include "avr_port.h"

enum { VT_COMMIT_NONE, VT_COMMIT_SCHEDULED, VT_COMMIT_DONE };
extern volatile uint8_t vt_commit_state;
extern volatile uint8_t vt_commit_onsets;     /* pulses start in the set: sync, re-phase */
extern volatile uint32_t vt_commit_tick;      /* the tick it is to go out at */
extern volatile uint64_t vt_commit_t;         /* when it went out (VT_COMMIT_DONE) */

/* The drive's hook (see above). */
void vt_out_commit_prepare(void);

/* In the preparation of tick k + 1 (k: the tick now): nonzero if the committed set goes
 * out at it (or is late for its own tick: it goes out at once). */
static inline uint8_t vt_commit_due(uint32_t k)
{
    return vt_commit_state == VT_COMMIT_SCHEDULED && (int32_t)(vt_commit_tick - (k + 1)) <= 0;
}

/* In the tick interrupt, after vt_clock_tick(): the set prepared for this tick is on the
 * outputs since Timer1 read c. The main loop polls the core at once. */
static inline void vt_commit_applied(uint16_t c)
{
    vt_commit_t = vt_clock_now_at(c);
    vt_commit_state = VT_COMMIT_DONE;
    vt_out_event = 1;
}

/* Interrupts off: a set committed and not yet shown is abandoned (everything off). */
static inline void vt_commit_abandon(void) { vt_commit_state = VT_COMMIT_NONE; }

#endif
