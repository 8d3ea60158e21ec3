# CTest driver for firmware.cross_build: configures and builds the firmware's own project (firmware/
# CMakeLists.txt) for the STM32F411 with cmake/arm-none-eabi.cmake, warnings as errors, and checks the
# template image against the budget of DESIGN.md (32 KB flash, 16 KB RAM). Exits with SKIP_CODE when
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
execute_process(COMMAND "${ARM_SIZE}" "${WORK}/rotoscan_fw_template.elf" OUTPUT_VARIABLE size RESULT_VARIABLE rc)
if(NOT rc EQUAL 0 OR NOT size MATCHES "\n *([0-9]+)[ \t]+([0-9]+)[ \t]+([0-9]+)")
  message(FATAL_ERROR "arm-none-eabi-size failed:\n${size}")
endif()
math(EXPR flash "${CMAKE_MATCH_1} + ${CMAKE_MATCH_2}")
math(EXPR ram "${CMAKE_MATCH_2} + ${CMAKE_MATCH_3}")
message("firmware core + protocol image (template port): flash ${flash} B of 32768, RAM ${ram} B of 16384")
if(flash GREATER 32768 OR ram GREATER 16384)
  message(FATAL_ERROR "over the image budget")
endif()
