# Helpers shared by every folder.

# kinevis_library(NAME ALIAS SOURCES...) is not worth a macro: folders call add_library directly
# and then kinevis_target_defaults() to get the include root and the warning flags.
function(kinevis_target_defaults target)
  target_include_directories(${target} PUBLIC $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}>)
  target_compile_options(${target} PRIVATE ${KINEVIS_WARNINGS})
endfunction()

# kinevis_add_test(hal/can/can_frame_test [LIBS lib...] [LABELS l...] [TIMEOUT s] [RUN_SERIAL])
# One line registers one test file: tests/<path>.cc becomes an executable whose GoogleTest
# cases are discovered as individual ctest tests. ctest runs tests two at a time (scripts/test);
# RUN_SERIAL marks a file whose cases must run alone (whole-program tests that hold real-time
# loops to deadlines).
function(kinevis_add_test path)
  cmake_parse_arguments(ARG "RUN_SERIAL" "TIMEOUT" "LIBS;LABELS" ${ARGN})
  string(REPLACE "/" "_" target "${path}")
  add_executable(${target} ${PROJECT_SOURCE_DIR}/tests/${path}.cc)
  kinevis_target_defaults(${target})
  target_link_libraries(${target} PRIVATE ${ARG_LIBS} kinevis_test_utilities GTest::gmock GTest::gtest_main)
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 120)
  endif()
  set(properties TIMEOUT ${ARG_TIMEOUT} ENVIRONMENT "KINEVIS_BINARY_DIR=${PROJECT_BINARY_DIR}")
  if(ARG_LABELS)
    list(APPEND properties LABELS "${ARG_LABELS}")
  endif()
  if(ARG_RUN_SERIAL)
    list(APPEND properties RUN_SERIAL TRUE)
  endif()
  gtest_discover_tests(${target}
    WORKING_DIRECTORY ${PROJECT_BINARY_DIR}
    DISCOVERY_TIMEOUT 60
    PROPERTIES ${properties})
endfunction()
