# Installs the build in BUILD_DIR into WORK_DIR/prefix and uses it as another project would:
#  1. builds EXAMPLE_DIR against it with find_package(rotoscan) and runs the example;
#  2. builds the same example with `pkg-config --cflags --libs rotoscan` (rotoscan.pc) and runs it;
#  3. moves the prefix elsewhere and runs the installed `rotoscan --version` and real subcommands from there
#     (simulate small calibration bundles and a scan, process the scan): the program finds its libraries
#     through its $ORIGIN RUNPATH;
#  4. puts the prefix back and runs the second example, calibrate_and_scan, on those bundles: it calibrates,
#     processes, meshes and prints the mesh's distance to the true surface, checked against a tolerance.
# Run by CTest (host/tests/CMakeLists.txt); fails on any step. Inputs: BUILD_DIR, EXAMPLE_DIR, WORK_DIR,
# SANITIZE, GENERATOR, CXX (compiler), PKG_CONFIG (executable), LIBDIR (CMAKE_INSTALL_LIBDIR).
file(REMOVE_RECURSE "${WORK_DIR}")
file(MAKE_DIRECTORY "${WORK_DIR}")
# Nothing may find the libraries but the installed files themselves.
unset(ENV{LD_LIBRARY_PATH})

function(run_step what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE result OUTPUT_VARIABLE output ERROR_VARIABLE output)
  message(STATUS "${what}:\n${output}")
  if(NOT result EQUAL 0)
    message(FATAL_ERROR "${what} failed (${result})")
  endif()
  set(step_output "${output}" PARENT_SCOPE)
endfunction()

set(prefix "${WORK_DIR}/prefix")
run_step("install" "${CMAKE_COMMAND}" --install "${BUILD_DIR}" --prefix "${prefix}")

# 1. find_package(rotoscan)
set(extra_flags "")
set(sanitize_flags "")
if(SANITIZE)
  set(sanitize_flags -fsanitize=address,undefined)
  set(extra_flags "-DCMAKE_CXX_FLAGS=-fsanitize=address,undefined" "-DCMAKE_EXE_LINKER_FLAGS=-fsanitize=address,undefined")
endif()
run_step("configure example" "${CMAKE_COMMAND}" -S "${EXAMPLE_DIR}" -B "${WORK_DIR}/build" -G "${GENERATOR}"
  "-DCMAKE_PREFIX_PATH=${prefix}" -DCMAKE_BUILD_TYPE=Release ${extra_flags})
run_step("build example" "${CMAKE_COMMAND}" --build "${WORK_DIR}/build")
# The installed libraries are found through the executable's RUNPATH, which CMake sets to the prefix.
run_step("run example" "${WORK_DIR}/build/project_points")

# 2. pkg-config: the flags of rotoscan.pc alone build and link the example.
set(ENV{PKG_CONFIG_PATH} "${prefix}/${LIBDIR}/pkgconfig")
run_step("pkg-config --cflags --libs rotoscan" "${PKG_CONFIG}" --cflags --libs rotoscan)
string(STRIP "${step_output}" pc_flags)
separate_arguments(pc_flags UNIX_COMMAND "${pc_flags}")
run_step("build example with pkg-config" "${CXX}" -std=c++17 ${sanitize_flags} "${EXAMPLE_DIR}/project_points.cc"
  ${pc_flags} "-Wl,-rpath,${prefix}/${LIBDIR}" -o "${WORK_DIR}/project_points_pc")
run_step("run example built with pkg-config" "${WORK_DIR}/project_points_pc")

# 3. The prefix moved after install: nothing may point to where it was installed.
set(moved "${WORK_DIR}/moved/elsewhere")
file(MAKE_DIRECTORY "${WORK_DIR}/moved")
file(RENAME "${prefix}" "${moved}")
set(rotoscan "${moved}/bin/rotoscan")
run_step("rotoscan --version from the moved prefix" "${rotoscan}" --version)
if(NOT step_output MATCHES "rotoscan [0-9]+\\.[0-9]+")
  message(FATAL_ERROR "rotoscan --version printed no version")
endif()
# Small renders (640x480, 3 x 8 calibration views, a 60-step scan of a sphere): seconds, not minutes. The
# board is 9 x 7 inner corners of 7 mm: at this image size the demo's 4 mm squares are too small for the
# corner detector at the most turned views (1.7 px corner RMS against 0.05 px here).
set(camera "\"camera\": {\"width\": 640, \"height\": 480, \"hfov_deg\": 20}")
set(board "\"type\": \"checkerboard\", \"cols\": 9, \"rows\": 7, \"square_mm\": 7")
set(placements "\"position_mm\": [20, 20, 0]" "\"position_mm\": [-20, -20, 0]"
  "\"position_mm\": [0, 25, 0], \"rotation_deg\": [-25, 0, 0]")
set(calibration_bundles "")
set(seed 1)
foreach(placement IN LISTS placements)
  file(WRITE "${WORK_DIR}/calibration-${seed}.json"
    "{\"seed\": ${seed}, ${camera}, \"objects\": [{${board}, ${placement}}]}\n")
  run_step("rotoscan simulate (calibration ${seed}) from the moved prefix" "${rotoscan}" --no-progress simulate
    "${WORK_DIR}/calibration-${seed}.json" --kind table-checkerboard --steps 8 --threads 2
    --out "${WORK_DIR}/calibration-${seed}")
  list(APPEND calibration_bundles "${WORK_DIR}/calibration-${seed}")
  math(EXPR seed "${seed} + 1")
endforeach()
file(WRITE "${WORK_DIR}/sphere.json"
  "{\"seed\": 4, ${camera}, \"table\": {\"step_deg\": 6}, \"objects\": [{\"type\": \"sphere\", \"radius_mm\": 20}]}\n")
run_step("rotoscan simulate (scan) from the moved prefix" "${rotoscan}" --no-progress simulate "${WORK_DIR}/sphere.json"
  --steps 60 --threads 2 --out "${WORK_DIR}/sphere-scan")
run_step("rotoscan process from the moved prefix" "${rotoscan}" --no-progress process "${WORK_DIR}/sphere-scan"
  --out "${WORK_DIR}/sphere-cloud.ply")
if(NOT step_output MATCHES "wrote [1-9][0-9]* points")
  message(FATAL_ERROR "rotoscan process wrote no points")
endif()

# 4. The second example on those bundles (the prefix back where the examples were built against it).
file(RENAME "${moved}" "${prefix}")
run_step("run calibrate_and_scan" "${WORK_DIR}/build/calibrate_and_scan" "${WORK_DIR}/sphere-scan"
  ${calibration_bundles})
# Tolerance: the mesh's median distance from the true sphere within 0.1 mm, under one pixel's footprint on
# the object (0.16 mm at 640 px) and 5x what this calibration gives (0.017 mm measured on 2026-11-24).
if(NOT step_output MATCHES "distance to the truth: median ([0-9.]+) mm")
  message(FATAL_ERROR "calibrate_and_scan printed no distance to the truth")
endif()
set(median "${CMAKE_MATCH_1}")
if(NOT median LESS 0.1)
  message(FATAL_ERROR "calibrate_and_scan: the mesh lies a median ${median} mm from the truth (tolerance 0.1 mm)")
endif()
message(STATUS "mesh from the calibrated rig: median ${median} mm from the true sphere (tolerance 0.1 mm)")
