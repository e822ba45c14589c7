# CMake helpers every package of the workspace uses (installed with robot_common; a package gets
# them with find_package(catkin REQUIRED COMPONENTS robot_common ...)).

# robot_common_add_tests(TEST_DIR [LAUNCH_DIR]): the package's tests for catkin: its pytest suite
# (robot_common_add_pytests) and, when given, a roslaunch-check of every launch file in LAUNCH_DIR.
function(robot_common_add_tests test_dir)
  if(DEFINED CATKIN_ENABLE_TESTING AND NOT CATKIN_ENABLE_TESTING)
    return()
  endif()
  if(ARGC GREATER 1)
    find_package(roslaunch REQUIRED)
    roslaunch_add_file_check(${ARGV1})
  endif()
  robot_common_add_pytests(${test_dir})
endfunction()

# robot_common_add_pytests(DIR): register the package's pytest suite in DIR with catkin, so that
# `catkin_make run_tests` (or `make run_tests_<package>`) runs it and leaves JUnit XML in
# build/test_results/<package>/pytest-<package>.xml for catkin_test_results. pytest finds the
# workspace's pytest.ini and conftest.py above the package (the ros_harness fixtures: real roscore
# and database servers); run it in the workspace's environment (source env.sh).
function(robot_common_add_pytests test_dir)
  if(DEFINED CATKIN_ENABLE_TESTING AND NOT CATKIN_ENABLE_TESTING)
    return()
  endif()
  get_filename_component(_dir "${test_dir}" ABSOLUTE BASE_DIR "${PROJECT_SOURCE_DIR}")
  if(NOT IS_DIRECTORY "${_dir}")
    message(FATAL_ERROR "robot_common_add_pytests(): '${_dir}' is not a directory")
  endif()
  set(_results "${CATKIN_TEST_RESULTS_DIR}/${PROJECT_NAME}")
  set(_xml "pytest-${PROJECT_NAME}.xml")
  catkin_run_tests_target("pytest" "${PROJECT_NAME}" "${_xml}"
    COMMAND "${CMAKE_COMMAND} -E make_directory ${_results}"
            "${PYTHON_EXECUTABLE} -m pytest ${_dir} -p no:cacheprovider --junitxml=${_results}/${_xml}"
    WORKING_DIRECTORY "${_dir}")
endfunction()
