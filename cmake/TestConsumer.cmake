# Installs the build in BUILD_DIR into WORK_DIR/prefix, builds EXAMPLE_DIR against it and runs the example.
# Run by CTest (host/tests/CMakeLists.txt); fails on any step.
file(REMOVE_RECURSE "${WORK_DIR}")
file(MAKE_DIRECTORY "${WORK_DIR}")

function(run_step what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE result OUTPUT_VARIABLE output ERROR_VARIABLE output)
  message(STATUS "${what}:\n${output}")
  if(NOT result EQUAL 0)
    message(FATAL_ERROR "${what} failed (${result})")
  endif()
endfunction()

run_step("install" "${CMAKE_COMMAND}" --install "${BUILD_DIR}" --prefix "${WORK_DIR}/prefix")
set(extra_flags "")
if(SANITIZE)
  set(extra_flags "-DCMAKE_CXX_FLAGS=-fsanitize=address,undefined" "-DCMAKE_EXE_LINKER_FLAGS=-fsanitize=address,undefined")
endif()
run_step("configure example" "${CMAKE_COMMAND}" -S "${EXAMPLE_DIR}" -B "${WORK_DIR}/build" -G "${GENERATOR}"
  "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix" -DCMAKE_BUILD_TYPE=Release ${extra_flags})
run_step("build example" "${CMAKE_COMMAND}" --build "${WORK_DIR}/build")
# The installed libraries are found through the executable's RUNPATH, which CMake sets to the prefix.
run_step("run example" "${WORK_DIR}/build/project_points")
