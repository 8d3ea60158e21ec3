# Helper functions shared by every CMakeLists.txt of the host build. Targets only: no directory-wide
# include_directories, every dependency stated on the target that needs it.

function(rotoscan_setup_warnings)
  set(common -Wall -Wextra -Wpedantic -Wshadow)
  set(cxx_only -Wnon-virtual-dtor -Woverloaded-virtual)
  set(c_only -Wstrict-prototypes -Wmissing-prototypes)
  add_compile_options("$<$<COMPILE_LANGUAGE:CXX>:${common};${cxx_only}>" "$<$<COMPILE_LANGUAGE:C>:${common};${c_only}>")
  if(ROTOSCAN_WERROR)
    add_compile_options(-Werror)
  endif()
endfunction()

# ASan + UBSan for everything built in this tree (tests run under it with -DROTOSCAN_SANITIZE=ON).
function(rotoscan_enable_sanitizers)
  set(flags -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  add_compile_options(${flags})
  add_link_options(${flags})
endfunction()

# rotoscan_add_module(NAME <module> SOURCES ... [PUBLIC_DEPS ...] [PRIVATE_DEPS ...])
# One library per host module: target rotoscan_<module>, alias rotoscan::<module>, exported as
# rotoscan::<module>. Public headers live in host/lib/include/rotoscan/<module>/.
function(rotoscan_add_module)
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;PUBLIC_DEPS;PRIVATE_DEPS" ${ARGN})
  set(target rotoscan_${ARG_NAME})
  add_library(${target} ${ARG_SOURCES})
  add_library(rotoscan::${ARG_NAME} ALIAS ${target})
  target_compile_features(${target} PUBLIC cxx_std_17)
  target_include_directories(${target}
    PUBLIC "$<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}/host/lib/include>" "$<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>"
    PRIVATE "${PROJECT_SOURCE_DIR}/host/lib/src")
  target_link_libraries(${target} PUBLIC ${ARG_PUBLIC_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
  set_target_properties(${target} PROPERTIES
    EXPORT_NAME ${ARG_NAME}
    OUTPUT_NAME rotoscan_${ARG_NAME}
    VERSION ${PROJECT_VERSION}
    SOVERSION ${PROJECT_VERSION_MAJOR}.${PROJECT_VERSION_MINOR}
    INSTALL_RPATH "$ORIGIN")  # the other modules lie beside it (the top-level CMakeLists.txt)
  install(TARGETS ${target} EXPORT rotoscanTargets
    LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
    ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
    RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  set_property(GLOBAL APPEND PROPERTY ROTOSCAN_MODULES ${target})
endfunction()

# rotoscan_add_test(NAME <name> SOURCES ... [DEPS ...] [LABELS ...])
# A GoogleTest executable registered with CTest (one CTest entry per test case). Test data are found
# through the ROTOSCAN_SOURCE_DIR definition.
function(rotoscan_add_test)
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;DEPS;LABELS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SOURCES})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS} rotoscan_testing GTest::gmock GTest::gtest_main)
  include(GoogleTest)
  # One label through gtest_discover_tests (it flattens lists), all of them afterwards (below).
  list(GET ARG_LABELS 0 first_label)
  gtest_discover_tests(${ARG_NAME} DISCOVERY_TIMEOUT 60 PROPERTIES LABELS "${first_label}")
  list(LENGTH ARG_LABELS n_labels)
  if(n_labels GREATER 1)
    rotoscan_label_discovered_tests(${ARG_NAME} "${ARG_LABELS}")
  endif()
endfunction()

# gtest_discover_tests (CMake 3.25) flattens a list in its PROPERTIES: LABELS "hil;firmware" becomes LABELS hil
# and a property named firmware, and every property after it is lost (the fixture, the timeout). A target's
# tests get their list of labels here instead, once discovered: CTest includes this file after the
# discovered tests, whose names are in <target>_TESTS.
function(rotoscan_label_discovered_tests target labels)
  set(file "${CMAKE_CURRENT_BINARY_DIR}/${target}_labels.cmake")
  file(WRITE "${file}" "if(${target}_TESTS)\n  set_tests_properties(\${${target}_TESTS} PROPERTIES LABELS \"${labels}\")\nendif()\n")
  set_property(DIRECTORY APPEND PROPERTY TEST_INCLUDE_FILES "${file}")
endfunction()

# rotoscan_add_benchmark(NAME <name> SOURCES ... [DEPS ...])
function(rotoscan_add_benchmark)
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;DEPS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SOURCES})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS} benchmark::benchmark benchmark::benchmark_main)
endfunction()
