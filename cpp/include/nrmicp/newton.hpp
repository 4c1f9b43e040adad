// nrmicp — the Newton member: a semismooth Newton method on the modulus equation of Theorem 3.1,
//
//   F(x) = (Ω2 + AΩ1)x − (Ω2 − AΩ1)|x| + γ(Aζ + q) = 0,
//
// with nested iteration over user-supplied prolongations and a fallback to the paper's
// iteration (docs/SPEC.md, "The Newton member"). A step with D = diag(sign x) solves the piece
// of F on which x lies: with the inactive set ℐ = {x ≥ 0} (z − ζ > 0, w = 0) and the active set
// 𝒜 = {x < 0} (z − ζ = 0), i.e. x ≥ 0 ⇔ (z − ζ)/Ω1 ≥ w/Ω2 (ties: ActiveSetTest::active_set):
//   (Az + q)_ℐ = 0,   (z − ζ(z))_𝒜 = 0            (detail/active_set.hpp)
// and x⁺ is recovered by the start formula x = γ/2 (Ω1⁻¹ g − Ω2⁻¹ w). For an LCP this is the
// primal–dual active-set method; on each piece F is affine, so the step is exact there. With
// bounds (Zeta::with_upper, or a constant ζ with −∞ entries) the obstacle path solves the box
// problem ζ ≤ z ≤ u, each row at its lower bound, at its upper one or inactive (detail/box.hpp);
// bounds that depend on z (an affine or callable ζ with u, an implicit u(z)) the outer fixed point,
// each outer step that box problem with the bounds frozen at its z (detail/outer_fixed_point.hpp).
//
// The structure: the step runs in the family's loop (detail::loop, solver.hpp) with the family's
// stopping Monitor, like every member's step.
//   detail/newton_level.hpp   one level: its matrix, the active-set test, the reduced systems, the
//                             fallback member
//   detail/newton_step.hpp    the plain step, with ζ's linearization as a policy: fixed (the
//                             shifted LCP, an affine ζ) or the Jacobian of a callable ζ at each z
//   detail/globalization.hpp  Globalized<Step>: non-monotone acceptance, cycles, fallback sweeps
//                             of nrm from the best iterate, and the step's own ends (settled
//                             active set, a fallback that brings nothing, maxiter Newton steps)
//   detail/outer_fixed_point.hpp  the outer fixed point on a callable ζ without Jacobian, a step
//                             of the same loop
//   detail/newton_run.hpp     one solve: newton_loop (one level: step + wrapper + Monitor), nested
//                             iteration, the strategy for each kind of ζ, the tally of statistics
//   this file                 nrmicp::Newton: the set-up of the levels and the API.
#pragma once

#include "detail/multigrid.hpp"
#include "detail/newton_level.hpp"
#include "detail/newton_run.hpp"
#include "detail/sparse_product.hpp"
#include "detail/timer.hpp"
#include "options.hpp"
#include "result.hpp"
#include "solver.hpp"
#include "splitting.hpp"
#include "zeta.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace nrmicp {

/// What became of the prolongations given to nrmicp::Newton: `requested` levels (1 + the
/// prolongations), `used` (Newton::levels()) and, when fewer are used, why ("" when all are).
struct HierarchyReport {
  int requested = 1;
  int used = 1;
  std::string reason;
};

/// The Newton member. Set-up once (coarse operators PᵀAP, symbolic analyses on first use);
/// solve(q, ζ) many times. `A` is held by reference and must outlive the object. Concurrent
/// solves on one object are serialized (the factorizations are reused state).
///
/// `prolongations` P_0, P_1, ...: P_0 maps level 1 (n_1 unknowns) to the finest level (n), P_l
/// level l+1 to level l. Coarse problems A_{l+1} = P_lᵀ A_l P_l, q_{l+1} = P_lᵀ q_l are solved
/// coarse to fine, each solution prolongated, projected onto z ≥ ζ and used as the next start.
/// `coarse_operators` (optional, one per prolongation): those A_{l+1} when the caller has formed
/// them already (an AMG set-up does), taken as they are instead of being formed again.
template <typename MatrixType>
class Newton {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using RowMatrix = typename detail::Engine<MatrixType>::Coarse;  ///< P, its coarse operators
  using Callback = detail::Callback;
  using Poll = detail::Poll;
  using Progress = detail::Progress;

  /// `options.method` is taken as Method::Newton (this class is the Newton member), so the
  /// options the Newton member does not have (phi, accelerate, z_update) are refused.
  Newton(const MatrixType& A, Options options, std::vector<RowMatrix> prolongations = {},
         std::vector<RowMatrix> coarse_operators = {})
      : options_(as_newton(std::move(options))), levels_{A, {}, {}, {}} {
    using detail::comm_of, detail::check_operator;  // (rows and columns below: this process's)
    detail::collective_check(comm_of(A), [&] { check_operator(A); });  // (the engine's layout first: collective calls)
    detail::collective_check(comm_of(A), [&] {
      if (A.rows() != A.cols() || (!A.rows() && comm_of(A).size() > 1))  // (each process decides on its rows)
        throw std::invalid_argument("Newton: A must be square with rows on every process, got " + std::to_string(A.rows()) + "x" + std::to_string(A.cols()));
      options_.check(A.rows(), detail::Engine<MatrixType>::serial);
    });
    check_shapes([&] { using detail::global_rows; return global_rows(A); }(), prolongations, coarse_operators);
    const auto t0 = std::chrono::steady_clock::now();
    levels_.finest = std::make_unique<detail::NewtonLevel<MatrixType>>(A, options_);  // checks Ω1, Ω2
    build_hierarchy(std::move(prolongations), std::move(coarse_operators));
    setup_timings_.setup = detail::ScopedTimer::seconds_since(t0);
  }

  const Options& options() const { return options_; }
  /// The constructor's seconds (setup: the levels and Galerkin operators; no factorization is
  /// done there). A solve's Result::timings count only that solve's call (result.hpp).
  const Timings& setup_timings() const { return setup_timings_; }
  /// Ω1, Ω2 (of the active-set test x > 0 ⇔ (z − ζ)/Ω1 > w/Ω2) and γ with defaults resolved;
  /// computed when asked (a solve needs only Ω1/Ω2: four n-vectors not held).
  Parameters parameters() const { return resolve_parameters(levels_.A, options_); }
  /// The inner solver of the reduced systems ("none" before the first solve).
  const char* inner_name() const { return levels_.finest->inner_name(); }
  /// Number of levels (1 without prolongations; fewer than given when hierarchy() says why).
  int levels() const { return levels_.count(); }
  /// The levels requested and used, and why a level was given up (build_hierarchy's rule).
  const HierarchyReport& hierarchy() const { return report_; }

  /// Solves ICP(q, A, ζ). The start: with prolongations, the nested coarse-to-fine solution, unless
  /// ζ is none or constant and z0 is nonzero and closer than a cold start by Res (z0 is then tried for
  /// NewtonTuning::warm_steps finest steps, the prolongations serving the inner solves: a time step's
  /// previous solution); without, z0 (zeros when null). `solve_options`, when given, replace the constructor's
  /// per-solve options (SolveOptions says which the Newton member uses).
  Result solve(const Vector& q, const Zeta<StorageIndex>& zeta = Zeta<StorageIndex>::none(), const Vector* z0 = nullptr,
               const Callback& callback = {}, const Poll& poll = {}, const SolveOptions* solve_options = nullptr,
               const Progress& progress = {}) const {
    const Busy busy(*this);
    Options o = options_;
    if (solve_options) detail::collective_check(levels_.finest->comm(), [&] { o = options_.with(solve_options, levels_.A.rows()); });
    return run(q, zeta, z0, {callback, poll, progress}, o, levels() > 1);
  }

  /// Polish: Newton steps from z on its active set (no nesting) until Res < tol or Res reaches
  /// its rounding floor (the rule of the Newton loop: the set repeats, or a step does not reduce
  /// Res there; STAGNATED, the message gives the floor), at most polish_steps. Returns the best
  /// iterate, z included.
  Result polish(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& z, double tol) const {
    const Busy busy(*this);
    Options o = options_;
    o.tol = tol, o.rtol = 0.0;  // (tol is the polish's target: a set-up's rtol, met at z already, takes no step)
    o.maxiter = polish_steps;
    o.record_history = false;
    return run(q, zeta, &z, {Callback(), Poll(), Progress()}, o, false);  // (none: temporaries outlive the call)
  }

 private:
  /// One step lands a member's answer on the rounding floor; a second one shows it is there.
  static constexpr int polish_steps = 3;

  /// Held by a solve: solves from other threads wait for it (the levels' systems are shared); one
  /// from the same thread, inside this solve's callback or ζ, would wait for itself: it throws.
  class Busy {
   public:
    explicit Busy(const Newton& n) : n_(n) {
      if (n.owner_.load() == std::this_thread::get_id())
        throw std::logic_error("Newton::solve called from inside a solve of the same solver (its callback or zeta): "
                               "a solve is not re-entrant; use a second solver for the inner problem");
      lock_ = std::unique_lock<std::mutex>(n.mutex_);
      n.owner_.store(std::this_thread::get_id());
    }
    ~Busy() { n_.owner_.store(std::thread::id()); }
    Busy(const Busy&) = delete;
    Busy& operator=(const Busy&) = delete;

   private:
    const Newton& n_;
    std::unique_lock<std::mutex> lock_;
  };

  static Options as_newton(Options o) {
    o.method = Method::Newton;
    return o;
  }

  /// The shape of the whole matrix (every process's rows).
  static std::string shape(const RowMatrix& M) {
    using detail::global_cols;
    using detail::global_rows;
    return std::to_string(global_rows(M)) + "x" + std::to_string(global_cols(M));
  }
  static void check_shapes(Eigen::Index rows, const std::vector<RowMatrix>& prolongations,
                           const std::vector<RowMatrix>& coarse) {
    if (!coarse.empty() && coarse.size() != prolongations.size())
      throw std::invalid_argument("Newton: " + std::to_string(coarse.size()) + " coarse_operators for " +
                                  std::to_string(prolongations.size()) + " prolongations (one each, or none)");
    using detail::global_cols;
    using detail::global_rows;
    for (std::size_t l = 0; l < prolongations.size(); ++l) {
      const RowMatrix& P = prolongations[l];
      if (global_rows(P) != rows || global_cols(P) < 1 || global_cols(P) > rows)
        throw std::invalid_argument("Newton: prolongations[" + std::to_string(l) + "] has shape " + shape(P) +
                                    ", expected " + std::to_string(rows) + " rows and at most as many columns");
      rows = global_cols(P);
      if (!coarse.empty() && (global_rows(coarse[l]) != rows || global_cols(coarse[l]) != rows))
        throw std::invalid_argument("Newton: coarse_operators[" + std::to_string(l) + "] has shape " +
                                    shape(coarse[l]) + ", expected " + std::to_string(rows) + "x" + std::to_string(rows));
    }
  }

  /// Galerkin coarse operators (formed here unless given); a level whose operator has a
  /// non-positive diagonal ends the hierarchy there (the active-set test needs Ω2 = diag > 0),
  /// and report_ says which level and row.
  void build_hierarchy(std::vector<RowMatrix> prolongations, std::vector<RowMatrix> coarse) {
    // Eigen 3.4's SparseMatrix has no move constructor: std::move copies it. The matrices are
    // swapped into place and the vector reserved (its growth would copy every level so far).
    using detail::comm_of;
    using detail::galerkin;
    using detail::transpose;
    auto& hierarchy = levels_.hierarchy;
    hierarchy.reserve(prolongations.size());
    for (std::size_t l = 0; l < prolongations.size(); ++l) {
      const RowMatrix* finer_A = hierarchy.empty() ? nullptr : &hierarchy.back().A;
      typename detail::Engine<MatrixType>::Level& level = hierarchy.emplace_back();
      level.P.swap(prolongations[l]);
      level.R = transpose(level.P);
      if (!coarse.empty()) {
        level.A.swap(coarse[l]);
      } else {
        RowMatrix A = finer_A ? galerkin(level.R, *finer_A, level.P) : galerkin(level.R, levels_.A, level.P);
        level.A.swap(A);
      }
      report_.reason = nonpositive_diagonal(level.A, static_cast<int>(l) + 1);
      const detail::Comm& comm = comm_of(levels_.A);
      if (!comm.all(report_.reason.empty())) {  // (every process gives the level up, in the same words)
        if (comm.size() > 1) report_.reason = nonpositive_diagonal(level.A, static_cast<int>(l) + 1, &comm);
        hierarchy.pop_back();
        break;
      }
    }
    report_.requested = 1 + static_cast<int>(prolongations.size());
    report_.used = 1 + static_cast<int>(hierarchy.size());
    Options co;
    co.inner = options_.inner;
    for (auto& level : hierarchy)
      levels_.coarse.push_back(std::make_unique<detail::NewtonLevel<RowMatrix>>(level.A, co));
    typename detail::Engine<MatrixType>::Hierarchy below{hierarchy.data(), hierarchy.size()};
    levels_.finest->use_hierarchy(below, true);  // the finest level frees the A_l while it solves
    for (auto& level : levels_.coarse) level->use_hierarchy(below = below.below());
  }

  /// Why level `l`'s operator A_l cannot be a level (a_ii <= 0), or "": its first such row, or over the
  /// processes of `comm` the least a_ii (the same words on each: the rows are each process's own).
  static std::string nonpositive_diagonal(const RowMatrix& A, int l, const detail::Comm* comm = nullptr) {
    const Vector d = diagonal(A);
    Eigen::Index i = 0;
    while (i < d.size() && d[i] > 0) ++i;
    if (!comm && i == d.size()) return {};
    const double inf = std::numeric_limits<double>::infinity();
    const std::string what = comm ? " <= 0 (the least: " + to_text(-comm->max(d.size() ? -d.minCoeff() : -inf)) + ")"
                                  : " = " + to_text(d[i]) + " <= 0 at row " + std::to_string(i);
    return "the coarse operator P^T A P of level " + std::to_string(l) + " (prolongations[" + std::to_string(l - 1) +
           "]) has a_ii" + what + " (the active-set test needs a positive diagonal): the hierarchy ends above it";
  }

  Result run(const Vector& q, const Zeta<StorageIndex>& given, const Vector* z0, const detail::Hooks& hooks,
             const Options& o, bool nest) const {
    const auto t0 = std::chrono::steady_clock::now();
    const Eigen::Index n = levels_.A.rows();
    detail::collective_check(levels_.finest->comm(), [&] { detail::check_solve_input("Newton::solve", q, z0, given, n); });
    const auto agreed = detail::agree_upper(given, n, levels_.finest->comm());
    const Zeta<StorageIndex>& zeta = agreed ? *agreed : given;
    Options resolved = o;
    resolve_tolerance(resolved, q, zeta, levels_.finest->comm());
    detail::NewtonRun<MatrixType> run(levels_, resolved, hooks, nest, zeta.upper());
    const auto t_iterations = std::chrono::steady_clock::now();
    Result r = [&] {
      if (zeta.implicit_upper()) return run.solve_outer_fixed_point(q, zeta, z0);  // its steps freeze u(z) too
      switch (zeta.kind()) {
        case ZetaKind::None: return run.solve_obstacle(q, Vector(), z0, nest);  // ψ = 0
        case ZetaKind::Constant: return run.solve_obstacle(q, zeta.c(), z0, nest);
        case ZetaKind::Affine:  // with an upper bound: the outer fixed point (its inner solves take the box)
          if (zeta.upper().size()) return run.solve_outer_fixed_point(q, zeta, z0);
          if constexpr (detail::Engine<MatrixType>::serial) return run.solve_affine(q, zeta, z0);
          throw std::invalid_argument("Newton: an affine zeta (its full system) is not available on this engine");
        case ZetaKind::Functor: break;
      }
      if (!zeta.has_jacobian()) return run.solve_outer_fixed_point(q, zeta, z0);
      return run.solve_semismooth(q, zeta, z0);
    }();
    // all levels, nested start included; the set-up done on the way (the reduced systems' analyses,
    // the hierarchy's operators formed again) is setup's, not the loop's
    r.timings.iterations = std::max(0.0, detail::ScopedTimer::seconds_since(t_iterations) - r.timings.setup);
    r.timings.total = detail::ScopedTimer::seconds_since(t0);
    r.inner = inner_name();
    return r;
  }

  Options options_;
  detail::NewtonLevels<MatrixType> levels_;
  Timings setup_timings_;
  HierarchyReport report_;
  mutable std::mutex mutex_;
  mutable std::atomic<std::thread::id> owner_{};  // the thread inside solve or polish (Busy)
};

}  // namespace nrmicp
