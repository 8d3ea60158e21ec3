/*
 * Single-producer single-consumer ring buffers of fixed-size elements over caller-provided static storage.
 * One side may be an interrupt handler and the other the main loop: the producer only writes `head`, the
 * consumer only writes `tail`, each after (or before) the data it guards, with a compiler barrier between.
 * Indices run freely and wrap at 2^32; the capacity must be a power of two. No locks, no malloc.
 */
#ifndef ROTOSCAN_FIRMWARE_RING_H_
#define ROTOSCAN_FIRMWARE_RING_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  uint8_t* storage;       /* capacity * elem_size bytes */
  uint32_t capacity;      /* elements, a power of two */
  uint32_t elem_size;     /* bytes per element */
  volatile uint32_t head; /* written by the producer only: elements pushed so far */
  volatile uint32_t tail; /* written by the consumer only: elements popped so far */
} ring_t;

/* Returns -EINVAL if capacity is not a power of two (>= 1) or an argument is null. Context: main, before the
 * other side runs. */
int ring_init(ring_t* r, void* storage, uint32_t capacity, uint32_t elem_size);
/* Empties the ring. Only while neither side runs. */
void ring_clear(ring_t* r);

uint32_t ring_count(const ring_t* r);
uint32_t ring_space(const ring_t* r);

/* Producer: copies one element in; false if full. */
bool ring_push(ring_t* r, const void* elem);
/* Consumer: copies one element out; false if empty. */
bool ring_pop(ring_t* r, void* elem);
/* Consumer: copies the oldest element out without removing it; false if empty. */
bool ring_peek(const ring_t* r, void* elem);

/* Byte rings (elem_size 1): push all `n` bytes or none (false); pop up to `max`, returning the count. */
bool ring_write_all(ring_t* r, const uint8_t* data, uint32_t n);
uint32_t ring_write_some(ring_t* r, const uint8_t* data, uint32_t n);
uint32_t ring_read(ring_t* r, uint8_t* out, uint32_t max);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_RING_H_ */
