// nrmicp — header-only solvers for large sparse implicit complementarity problems
// ICP(q, A, ζ): w = Az + q ≥ 0, z − ζ(z) ≥ 0, (z − ζ(z))ᵀw = 0,
// by the new relaxation modulus-based (NRM) family. Include this one header.
#pragma once

#include "inner_solver.hpp"
#include "newton.hpp"
#include "options.hpp"
#include "result.hpp"
#include "solver.hpp"
#include "splitting.hpp"
#include "zeta.hpp"

#define NRMICP_VERSION_MAJOR 0
#define NRMICP_VERSION_MINOR 1
#define NRMICP_VERSION_PATCH 0
