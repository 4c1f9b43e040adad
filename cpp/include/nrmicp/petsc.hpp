// nrmicp on PETSc: the Newton member over MPI, nrmicp::Newton<nrmicp::petsc::Matrix> (the one
// driver of newton.hpp on the PETSc engine, petsc/engine.hpp), and the stationary members,
// nrmicp::Solver<nrmicp::petsc::Matrix> (the one loop of solver.hpp). Needs PETSc with hypre and MPI.
#pragma once

#include "petsc/engine.hpp"
#include "petsc/hierarchy.hpp"
#include "newton.hpp"
#include "solver.hpp"
