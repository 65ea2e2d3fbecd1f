/* Capacities of the host builds: the vector runner takes any configuration a vector
 * gives (pulse trains or levels, up to a 20x20 array), and the pty device any shipped
 * profile. The microcontroller builds size these to the chip (ports/avr/vt_profile.h). */
#ifndef VT_PROFILE_H
#define VT_PROFILE_H

#define VT_MAX_PULSES 4096
#define VT_MAX_PAYLOAD 1024
#define VT_MAX_ACTUATORS 400
#define VT_SETTING_BYTES 6          /* a pulse train's setting; a level uses the first */
#define VT_HAL_SCHEDULES_COMMITS 0  /* a set is applied when it is due, at once */

#endif
