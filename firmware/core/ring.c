#include "ring.h"

#include <errno.h>
#include <string.h>

#include "hal.h"

int ring_init(ring_t* r, void* storage, uint32_t capacity, uint32_t elem_size) {
  if (r == NULL || storage == NULL || elem_size == 0 || capacity == 0 || (capacity & (capacity - 1u)) != 0) {
    return -EINVAL;
  }
  r->storage = (uint8_t*)storage;
  r->capacity = capacity;
  r->elem_size = elem_size;
  r->head = 0;
  r->tail = 0;
  return 0;
}

void ring_clear(ring_t* r) {
  r->head = 0;
  r->tail = 0;
}

uint32_t ring_count(const ring_t* r) {
  return r->head - r->tail;
}
uint32_t ring_space(const ring_t* r) {
  return r->capacity - (r->head - r->tail);
}

bool ring_push(ring_t* r, const void* elem) {
  const uint32_t head = r->head;
  if (head - r->tail >= r->capacity) return false;
  memcpy(r->storage + (size_t)(head & (r->capacity - 1u)) * r->elem_size, elem, r->elem_size);
  HAL_BARRIER(); /* the element is written before it is published */
  r->head = head + 1u;
  return true;
}

bool ring_peek(const ring_t* r, void* elem) {
  const uint32_t tail = r->tail;
  if (r->head == tail) return false;
  HAL_BARRIER(); /* read the element only after seeing it published */
  memcpy(elem, r->storage + (size_t)(tail & (r->capacity - 1u)) * r->elem_size, r->elem_size);
  return true;
}

bool ring_pop(ring_t* r, void* elem) {
  if (!ring_peek(r, elem)) return false;
  HAL_BARRIER(); /* the element is read before its slot is released */
  r->tail = r->tail + 1u;
  return true;
}

uint32_t ring_write_some(ring_t* r, const uint8_t* data, uint32_t n) {
  uint32_t head = r->head;
  const uint32_t space = r->capacity - (head - r->tail);
  const uint32_t count = n < space ? n : space;
  for (uint32_t i = 0; i < count; ++i) r->storage[(head + i) & (r->capacity - 1u)] = data[i];
  HAL_BARRIER();
  r->head = head + count;
  return count;
}

bool ring_write_all(ring_t* r, const uint8_t* data, uint32_t n) {
  if (ring_space(r) < n) return false;
  return ring_write_some(r, data, n) == n;
}

uint32_t ring_read(ring_t* r, uint8_t* out, uint32_t max) {
  const uint32_t tail = r->tail;
  const uint32_t avail = r->head - tail;
  const uint32_t count = max < avail ? max : avail;
  HAL_BARRIER();
  for (uint32_t i = 0; i < count; ++i) out[i] = r->storage[(tail + i) & (r->capacity - 1u)];
  HAL_BARRIER();
  r->tail = tail + count;
  return count;
}
