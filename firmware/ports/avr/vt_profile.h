/* Capacities of an ATmega2560 build, and the check that they fit its 8 KiB of RAM.
 *
 * The profile header (firmware/profiles/NAME.h, chosen with PROFILE=NAME) says what
 * the array is; this file says how much of it the firmware holds. Override
 * VT_MAX_PULSES or VT_MAX_PAYLOAD on the make command line (see docs/firmware.md);
 * a choice that does not fit stops the build with a message (vt_core.c, main.c).
 */
#ifndef VT_PROFILE_H
#define VT_PROFILE_H

#include "vt_wire.h"

#ifdef VT_RUNNER
/* The vector runner: any configuration a vector gives, no outputs. */
#define VT_MAX_PULSES 64
#define VT_MAX_PAYLOAD 1024
#define VT_MAX_ACTUATORS 400
#define VT_SETTING_BYTES 6
#define VT_HAL_SCHEDULES_COMMITS 0
#define VT_RUNNER_LINE 1100
#define VT_RUNNER_OUTPUTS 0
#define VT_PORT_RAM_BYTES (256 + 256 + 2 * VT_RUNNER_LINE)
#else

#include VT_PROFILE_HEADER

#ifndef VT_MAX_PULSES
#if VT_DRIVE == VT_DRIVE_LEVEL
#define VT_MAX_PULSES 256           /* the largest shipped study needs 196 (six_mode_ball) */
#else
#define VT_MAX_PULSES 192           /* 16 bytes a pulse; the shipped SMA studies need 66 */
#endif
#endif
#ifndef VT_MAX_PAYLOAD
#if VT_DRIVE == VT_DRIVE_LEVEL
#define VT_MAX_PAYLOAD 512          /* a full 20x20 frame is 401 bytes */
#else
#define VT_MAX_PAYLOAD 256          /* a full 5x5 frame of trains is 151 bytes */
#endif
#endif
#define VT_MAX_ACTUATORS (VT_ROWS * VT_COLS)
#if VT_DRIVE == VT_DRIVE_LEVEL
#define VT_SETTING_BYTES 1          /* a level */
#else
#define VT_SETTING_BYTES 6          /* amplitude, frequency, width */
#endif
#define VT_HAL_SCHEDULES_COMMITS 1  /* sets are applied by the tick interrupt */

#if VT_DRIVE == VT_DRIVE_LEVEL
#define VT_TICK_US 1000             /* 1 kHz: 10 PWM slots make the 100 Hz carrier */
#define VT_PREPARE_AT 1700          /* compare B, 850 us into the tick: the next plane */
#define VT_CHAIN_BYTES ((VT_MAX_ACTUATORS + 7) / 8)     /* TPIC6B595s in the chain */
/* UART rings, two sets of 10 bit planes (active, staged), the port's variables */
#define VT_PORT_RAM_BYTES (256 + 128 + 2 * 10 * VT_CHAIN_BYTES + 64)
#else
#define VT_TICK_US 100              /* 10 kHz: pulse-train edges on a 100 us grid */
#define VT_PREPARE_AT 0             /* the tick interrupt prepares the next tick itself */
#define VT_DAC_CHIPS 4              /* LTC2656 octal DACs, daisy-chained */
/* UART rings; per pin its train (33 B), staged setting (18 B), DAC codes (4 B) and two
 * list places (4 B); the DAC transfers planned for a commit (8 x 16 B); the fall ring
 * (32 ticks x 4 B); the port's variables */
#define VT_PORT_RAM_BYTES (256 + 128 + 59 * VT_MAX_ACTUATORS + 128 + 128 + 64)
#endif

#endif /* VT_RUNNER */

/* A play starts at least this long after its TRIGGER: time to prepare its first instant
 * (up to about 1 ms at 16 MHz for 100 onsets at once) and whatever frame the host sent
 * meanwhile, before the tick. With the alignment to a tick, within the 5 ms that
 * docs/protocol.md allows. */
#define VT_START_LEAD_US 3000

#define VT_RAM_LIMIT 7680           /* 7.5 KiB of the 8 KiB: the rest is stack */
#define VT_STACK_RESERVE 384        /* measured deepest stack + interrupts, with margin */

#endif
