# CTest driver for firmware.cross_build: configures and builds the firmware's own project (firmware/
# CMakeLists.txt) for the STM32F411 with cmake/arm-none-eabi.cmake, warnings as errors, and checks the
# images (the STM32F411 board over USB and over UART, and the template port) against the budget of DESIGN.md
# (32 KB flash, 16 KB RAM), with their .map and .bin. Exits with SKIP_CODE when
# arm-none-eabi-gcc is not installed.
#   cmake -DSRC=<repo> -DWORK=<dir> -DGENERATOR=<gen> -DSKIP_CODE=<n> -P cross_build_test.cmake
find_program(ARM_GCC arm-none-eabi-gcc)
find_program(ARM_SIZE arm-none-eabi-size)
if(NOT ARM_GCC OR NOT ARM_SIZE)
  message("arm-none-eabi-gcc not found: cross build skipped")
  cmake_language(EXIT ${SKIP_CODE})
endif()
file(REMOVE_RECURSE "${WORK}")
execute_process(
  COMMAND "${CMAKE_COMMAND}" -S "${SRC}/firmware" -B "${WORK}" -G "${GENERATOR}"
    "-DCMAKE_TOOLCHAIN_FILE=${SRC}/cmake/arm-none-eabi.cmake" -DCMAKE_BUILD_TYPE=MinSizeRel
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "configuring the cross build failed:\n${out}${err}")
endif()
execute_process(COMMAND "${CMAKE_COMMAND}" --build "${WORK}" -j 2
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message("${out}")
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the cross build failed:\n${out}${err}")
endif()
if("${out}${err}" MATCHES "warning:")
  message(FATAL_ERROR "the cross build has warnings:\n${out}${err}")
endif()
# Each image against DESIGN.md's budget: flash = text + data, RAM = data + bss (the STM32F411 images' bss
# includes the fault record and the 4 KB stack reservation of port/stm32f411/stm32f411.ld).
foreach(image rotoscan-fw rotoscan-fw-uart rotoscan_fw_template)
  set(elf "${WORK}/${image}.elf")
  foreach(f "${elf}" "${WORK}/${image}.map")
    if(NOT EXISTS "${f}")
      message(FATAL_ERROR "the cross build did not produce ${f}")
    endif()
  endforeach()
  execute_process(COMMAND "${ARM_SIZE}" "${elf}" OUTPUT_VARIABLE size RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0 OR NOT size MATCHES "\n *([0-9]+)[ \t]+([0-9]+)[ \t]+([0-9]+)")
    message(FATAL_ERROR "arm-none-eabi-size failed:\n${size}")
  endif()
  math(EXPR flash "${CMAKE_MATCH_1} + ${CMAKE_MATCH_2}")
  math(EXPR ram "${CMAKE_MATCH_2} + ${CMAKE_MATCH_3}")
  message("${image}.elf: flash ${flash} B of 32768, RAM ${ram} B of 16384")
  if(flash GREATER 32768 OR ram GREATER 16384)
    message(FATAL_ERROR "${image} is over the image budget")
  endif()
endforeach()
# What dfu-util writes: the USB image as a raw binary starting with the vector table (initial stack pointer
# at the top of the F411's 128 KB of RAM, reset handler in flash, Thumb bit set).
foreach(image rotoscan-fw rotoscan-fw-uart)
  set(bin "${WORK}/${image}.bin")
  file(SIZE "${bin}" bin_size)
  file(READ "${bin}" head LIMIT 8 HEX)
  if(bin_size GREATER 32768 OR NOT head MATCHES "^00000220......0[89]")
    message(FATAL_ERROR "${bin}: not an STM32F411 image (${bin_size} B, starts ${head})")
  endif()
  message("${image}.bin: ${bin_size} B, vector table at 0x08000000")
endforeach()
