# The layering rule of docs/architecture.md, checked on every source file: a folder includes only
# the folders below it. Run by ctest (style.layering):
#   cmake -DKINEVIS_ROOT=<repository> -P cmake/check_layering.cmake
# Fails with every offending file:line and include, and with every entry of the list of known
# exceptions that no longer occurs (so that the list only shrinks).

cmake_minimum_required(VERSION 3.22)

if(NOT KINEVIS_ROOT)
  get_filename_component(KINEVIS_ROOT "${CMAKE_CURRENT_LIST_DIR}/.." ABSOLUTE)
endif()

# Project folders each folder may include (its own folder always).
set(allowed_common "")
set(allowed_hal "common")
set(allowed_robots "common")
set(allowed_vision "common;hal")
set(allowed_calibration "common;robots;vision")
set(allowed_control "common;hal;robots;vision")
set(allowed_sim "common;hal;robots;vision;calibration;control")
set(allowed_rigs "common;hal;robots;vision;calibration;control;sim")
set(allowed_apps "common;hal;robots;vision;calibration;control;sim;rigs")
set(allowed_tests "common;hal;robots;vision;calibration;control;sim;rigs")
# Benchmarks and experiments may use the tests' synthetic data (tests/utilities and the like).
set(allowed_bench "${allowed_tests};tests")
set(allowed_experiments "${allowed_tests};tests")
set(allowed_fuzz "common;hal")
set(project_folders common hal robots vision calibration control sim rigs apps tests bench
    experiments fuzz)

# Third-party headers a folder may not include (robots/ is Eigen and std only; its io/ part reads
# YAML files; in common/, only kinevis::common_yaml's yaml_reader.cc includes yaml-cpp, its header
# does not).
set(forbidden_system_robots "yaml-cpp/;opencv2/;visp3/;ceres/;spdlog/;CLI/;modbus")
set(forbidden_system_common "yaml-cpp/;opencv2/;visp3/;ceres/;CLI/;modbus")

# Known exceptions, "file -> included folder", each with the reason; remove an entry when it is
# fixed (the check fails while a listed exception no longer occurs).
set(known_exceptions
  # The renderer's hexapod scene draws the robot from its model (issue 17: the scene moves to sim/
  # or takes the leg geometry as plain points).
  "vision/render/scenes/hexapod_scene.h -> robots"
)

set(problems "")
set(seen_exceptions "")
foreach(folder IN LISTS project_folders)
  if(NOT IS_DIRECTORY "${KINEVIS_ROOT}/${folder}")
    continue()
  endif()
  file(GLOB_RECURSE sources RELATIVE "${KINEVIS_ROOT}"
       "${KINEVIS_ROOT}/${folder}/*.h" "${KINEVIS_ROOT}/${folder}/*.cc")
  foreach(source IN LISTS sources)
    file(STRINGS "${KINEVIS_ROOT}/${source}" lines REGEX "^[ \t]*#[ \t]*include")
    foreach(line IN LISTS lines)
      if(line MATCHES "#[ \t]*include[ \t]*\"([a-z_]+)/")
        set(target "${CMAKE_MATCH_1}")
        if(target STREQUAL folder OR NOT target IN_LIST project_folders)
          continue()
        endif()
        if(NOT target IN_LIST allowed_${folder})
          set(entry "${source} -> ${target}")
          if(entry IN_LIST known_exceptions)
            list(APPEND seen_exceptions "${entry}")
          else()
            string(STRIP "${line}" text)
            string(REPLACE ";" ", " may "${allowed_${folder}}")
            list(APPEND problems "${source}: ${text} (${folder}/ may include: ${may})")
          endif()
        endif()
      elseif(line MATCHES "#[ \t]*include[ \t]*<([^>]+)>")
        set(header "${CMAKE_MATCH_1}")
        foreach(prefix IN LISTS forbidden_system_${folder})
          string(FIND "${header}" "${prefix}" at)
          if(at EQUAL 0 AND NOT source MATCHES "^robots/io/" AND
             NOT source STREQUAL "common/yaml_reader.cc")
            string(STRIP "${line}" text)
            list(APPEND problems "${source}: ${text} (not allowed in ${folder}/)")
          endif()
        endforeach()
      endif()
    endforeach()
  endforeach()
endforeach()

foreach(entry IN LISTS known_exceptions)
  if(NOT entry IN_LIST seen_exceptions)
    list(APPEND problems "known exception \"${entry}\" no longer occurs: remove it from cmake/check_layering.cmake")
  endif()
endforeach()

if(problems)
  list(LENGTH problems count)
  string(REPLACE ";" "\n  " text "${problems}")
  message(FATAL_ERROR "layering: ${count} include(s) point up or sideways across the layers "
                      "(docs/architecture.md):\n  ${text}")
endif()
message(STATUS "layering: every include points down")
