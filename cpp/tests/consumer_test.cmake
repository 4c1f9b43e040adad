# Installs nrmicp into WORK_DIR/prefix, builds cpp/examples against it, runs the example.
# Then configures nrmicp with NRMICP_USE_SUITESPARSE=OFF, installs it into WORK_DIR/off-prefix and
# checks that the installed config keeps that choice: the example configured against it says
# "disabled" and is compiled without NRMICP_HAVE_CHOLMOD/UMFPACK (configured only, not built).
file(REMOVE_RECURSE ${WORK_DIR})
function(run)
  execute_process(COMMAND ${ARGV} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "command failed (${rc}): ${ARGV}\n${out}\n${err}")
  endif()
  message(STATUS "${out}")
  set(run_out "${out}" PARENT_SCOPE)
endfunction()
run(${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${WORK_DIR}/prefix)
run(${CMAKE_COMMAND} -S ${SOURCE_DIR}/cpp/examples -B ${WORK_DIR}/build -G ${GENERATOR}
    -DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix -DCMAKE_BUILD_TYPE=Release)
run(${CMAKE_COMMAND} --build ${WORK_DIR}/build)
run(${WORK_DIR}/build/obstacle_example)

run(${CMAKE_COMMAND} -S ${SOURCE_DIR} -B ${WORK_DIR}/off-build -G ${GENERATOR} -DNRMICP_USE_SUITESPARSE=OFF
    -DNRMICP_BUILD_TESTS=OFF -DNRMICP_BUILD_PYTHON=OFF)
if(NOT run_out MATCHES "CHOLMOD disabled \\(NRMICP_USE_SUITESPARSE=OFF\\)")
  message(FATAL_ERROR "configure with NRMICP_USE_SUITESPARSE=OFF did not say 'CHOLMOD disabled'")
endif()
run(${CMAKE_COMMAND} --install ${WORK_DIR}/off-build --prefix ${WORK_DIR}/off-prefix)
run(${CMAKE_COMMAND} -S ${SOURCE_DIR}/cpp/examples -B ${WORK_DIR}/off-example -G ${GENERATOR}
    -DCMAKE_PREFIX_PATH=${WORK_DIR}/off-prefix -DCMAKE_BUILD_TYPE=Release)
if(NOT run_out MATCHES "CHOLMOD disabled")
  message(FATAL_ERROR "the installed config of an OFF build did not say 'CHOLMOD disabled':\n${run_out}")
endif()
file(GLOB_RECURSE _files ${WORK_DIR}/off-example/*.ninja ${WORK_DIR}/off-example/*flags.make)
foreach(f ${_files})
  file(READ ${f} _text)
  if(_text MATCHES "NRMICP_HAVE_(CHOLMOD|UMFPACK)|cholmod|umfpack")
    message(FATAL_ERROR "the installed config of an OFF build linked SuiteSparse again (${f})")
  endif()
endforeach()
