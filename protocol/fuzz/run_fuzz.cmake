# CTest driver for protocol.fuzz_decoder: builds the libFuzzer target with clang (ASan + UBSan) into the
# build tree and runs it for a bounded number of inputs, starting from the golden frames. Exits with
# SKIP_CODE (CTest SKIP_RETURN_CODE) when clang or its fuzzer runtime is missing.
#   cmake -DCLANG=... -DSRC=<repo> -DWORK=<dir> -DRUNS=<n> -DSKIP_CODE=<n> -P run_fuzz.cmake
if(NOT CLANG OR NOT EXISTS "${CLANG}")
  message("clang not found: fuzzing skipped")
  cmake_language(EXIT ${SKIP_CODE})
endif()
file(REMOVE_RECURSE "${WORK}/corpus")  # a fresh corpus each run: bounded and repeatable
file(MAKE_DIRECTORY "${WORK}/corpus")
set(exe "${WORK}/decode_fuzz")
execute_process(
  COMMAND "${CLANG}" -std=c99 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined
    -Wall -Wextra -Werror -I "${SRC}/protocol/include"
    "${SRC}/protocol/fuzz/decode_fuzz.c" "${SRC}/protocol/src/codec.c" "${SRC}/protocol/src/cobs.c"
    "${SRC}/protocol/src/crc32.c" -o "${exe}"
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  if(err MATCHES "libclang_rt.fuzzer|cannot find|unsupported option")
    message("clang has no libFuzzer runtime: fuzzing skipped\n${err}")
    cmake_language(EXIT ${SKIP_CODE})
  endif()
  message(FATAL_ERROR "building the fuzz target failed:\n${out}${err}")
endif()
# Seeds: the golden frames, as raw bytes.
execute_process(COMMAND "${CLANG}" -std=c99 -O1 "${SRC}/protocol/fuzz/hex2bin.c" -o "${WORK}/hex2bin"
  RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "building hex2bin failed")
endif()
file(GLOB vectors "${SRC}/protocol/vectors/*.hex")
foreach(v IN LISTS vectors)
  get_filename_component(name "${v}" NAME_WE)
  execute_process(COMMAND "${WORK}/hex2bin" "${v}" "${WORK}/corpus/${name}" RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "converting ${v} failed")
  endif()
endforeach()
execute_process(
  COMMAND "${exe}" -runs=${RUNS} -seed=20261122 -max_len=512 -print_final_stats=1
    "-artifact_prefix=${WORK}/" "${WORK}/corpus"
  RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the fuzzer found a failure (exit ${rc}); the crashing input is in ${WORK}")
endif()
