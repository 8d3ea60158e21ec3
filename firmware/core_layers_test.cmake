# CTest driver for firmware.core_layers: the firmware core's modules include each other one way only (the
# order in core/state.h). Each file of core/ may include the headers of its own module and of modules before
# it, never after. fw.h is the port-facing header whose functions fw.c implements -- except fw_report, which
# state.c implements; state.c may include it for that declaration alone.
#   cmake -DCORE=<firmware/core> -P core_layers_test.cmake
set(order version ring timebase link stepper state motion sequencer status dispatch fw)
file(GLOB files "${CORE}/*.c" "${CORE}/*.h")
set(errors "")
foreach(f ${files})
  get_filename_component(self "${f}" NAME_WE)
  list(FIND order "${self}" self_layer)
  if(self_layer LESS 0)
    string(APPEND errors "${f}: module '${self}' is not in the layer order\n")
    continue()
  endif()
  file(STRINGS "${f}" includes REGEX "^#include \"[a-z_]+\\.h\"")
  foreach(line ${includes})
    string(REGEX REPLACE "^#include \"([a-z_]+)\\.h\".*" "\\1" dep "${line}")
    list(FIND order "${dep}" dep_layer)
    if(dep_layer LESS 0)
      continue() # hal.h, rotoscan_protocol.h: below the core
    endif()
    if(dep_layer GREATER self_layer AND NOT (self STREQUAL "state" AND dep STREQUAL "fw"))
      string(APPEND errors "${f}: includes ${dep}.h, a layer above ${self}\n")
    endif()
  endforeach()
endforeach()
if(errors)
  message(FATAL_ERROR "the firmware core includes upwards (order: ${order}):\n${errors}")
endif()
message("firmware core: one-way includes (${order})")
