// Options::check names the offending field and value.
#include <nrmicp/nrmicp.hpp>

#include <doctest/doctest.h>

#include <cmath>
#include <string>
#include <variant>

using nrmicp::Options;

TEST_CASE("default options are valid") { CHECK_NOTHROW(Options().check(10)); }

TEST_CASE("invalid fields are named in the error") {
  Options o;
  o.tol = -1;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("tol"), std::invalid_argument);
  o = Options(); o.gamma = 0;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("gamma"), std::invalid_argument);
  o = Options(); o.omega1 = Eigen::VectorXd::Ones(2);
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("omega1 must have length n = 3"), std::invalid_argument);
  o = Options(); o.omega2 = Eigen::Vector3d(1, -1, 1);
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("omega2[1]"), std::invalid_argument);
  o = Options(); o.phi = Eigen::Vector3d(0, NAN, 1);
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("phi[1]"), std::invalid_argument);
  o = Options(); o.theta = 2.5;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("theta"), std::invalid_argument);
  o = Options(); o.rtol = 1.0;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("rtol must lie in [0, 1)"), std::invalid_argument);
  o = Options(); o.rtol = NAN;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("rtol"), std::invalid_argument);
  o = Options(); o.tol = 0;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("tol must be a finite number > 0 (or 0 with rtol > 0)"),
                       std::invalid_argument);
  o.rtol = 1e-6;
  CHECK_NOTHROW(o.check(3));
  o = Options(); o.maxiter = -1;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("maxiter"), std::invalid_argument);
}

TEST_CASE("each number option is checked against its row of the option table") {
  for (const nrmicp::OptionSpec& spec : nrmicp::option_table) {
    const nrmicp::Range& r = spec.range;
    if (!r.bounded()) continue;
    // just outside: past a finite high bound, else the open low bound itself or one below the closed one
    const double bad = r.high < INFINITY ? r.high + 1 : (r.low_open ? r.low : r.low - 1);
    Options o;
    if (auto* f = std::get_if<double Options::*>(&spec.field)) o.*(*f) = bad;
    else if (auto* i = std::get_if<int Options::*>(&spec.field)) o.*(*i) = static_cast<int>(bad);
    else continue;  // the diagonals: checked entry by entry above
    CAPTURE(spec.name);
    const std::string expected = std::string(spec.name) + " must";
    CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains(expected.c_str()), std::invalid_argument);
  }
}

TEST_CASE("the option table names each option once, and the defaults lie in their ranges") {
  for (const nrmicp::OptionSpec& a : nrmicp::option_table)
    for (const nrmicp::OptionSpec& b : nrmicp::option_table)
      if (&a != &b) CHECK(std::string(a.name) != b.name);
  CHECK_NOTHROW(Options().check(3));
}
