/*
 * The scan sequencer (seq_): runs an uploaded scan program -- per table step: move, settle, and per shot:
 * lasers, trigger, wait for the exposure -- with no host round trip per frame, and single TRIGGER commands.
 * Laser switching and trigger edges are hardware compares scheduled from the main loop, so their timing
 * does not depend on main-loop latency; the trigger interrupt records the laser state and the position at
 * the edge, which is what TRIGGER_EVENT reports.
 */
#ifndef ROTOSCAN_FIRMWARE_SEQUENCER_H_
#define ROTOSCAN_FIRMWARE_SEQUENCER_H_

#include <stdbool.h>
#include <stdint.h>

#include "rotoscan_protocol.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Lead between scheduling a shot and its first compare, so the compare is never in the past. */
#define SEQ_ARM_MARGIN_US 100u
/* A trigger edge that has not been reported this long after its exposure ended is a fault. */
#define SEQ_TRIGGER_LOST_US 100000u

void seq_init(void);

/* Validates and stores a program; the table's origin is the position now. Returns PROTO_ST_OK or
 * PROTO_ST_BAD_VALUE / PROTO_ST_BUSY, with *field the 1-based field index for BAD_VALUE. Context: main. */
uint8_t seq_load(const proto_program_t* program, uint8_t* field);
/* Starts (or resumes) the program at `first_step`. Returns a PROTO_ST_* code. Context: main. */
uint8_t seq_start(uint32_t first_step, uint8_t* field);
/* One exposure outside a program. Returns a PROTO_ST_* code. Context: main. */
uint8_t seq_trigger(const proto_trigger_t* trigger, uint8_t* field);
/* Stops a program or trigger, cancels scheduled compares and turns the lasers off. Returns true if something
 * was running. Context: main. */
bool seq_abort(void);

/* SET_LASERS outside programs: the mask the lasers rest at. Context: main. */
void seq_set_idle_lasers(uint8_t mask);
uint8_t seq_idle_lasers(void);

/* Runs the state machine. Returns the cause of a STATUS event the caller must send (PROTO_CAUSE_PROGRAM_DONE
 * when a program ended, PROTO_CAUSE_ABORTED when a lost trigger edge stopped it), or SEQ_NO_STATUS: the
 * sequencer sits below the STATUS layer (state.h). Context: main. */
#define SEQ_NO_STATUS 0xFFu
uint8_t seq_poll(void);
/* Called by fw when a program move ends (motion_poll). Context: main. */
void seq_move_done(void);
/* Device time the sequencer next needs the main loop (UINT64_MAX if none). */
uint64_t seq_next_wakeup(void);

bool seq_running(void); /* a program is running */
bool seq_busy(void);    /* a program or a single trigger is running */
bool seq_program_loaded(void);
uint32_t seq_next_step(void); /* where a program continues (and where to resume after an abort) */
uint32_t seq_program_steps(void);
uint32_t seq_trigger_count(void);
/* Whether the lasers are, or are about to be, on because of a program or trigger. */
bool seq_lasers_in_use(void);
/* Whether the port reads the camera's exposure line (hal_exposure_capture_enable succeeded). */
bool seq_has_exposure_input(void);

/* Interrupt entry points (through fw_isr_*). Context: isr. */
void seq_isr_trigger(uint32_t at);
void seq_isr_exposure(uint32_t at, bool level);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_SEQUENCER_H_ */
