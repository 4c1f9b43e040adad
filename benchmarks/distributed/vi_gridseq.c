/* PETSc's SNES VI (vinewtonrsls) on the obstacle problem of nrmicp.scenes (−Δ_h u ≥ 0, u ≥ ψ,
   ψ = a − |x − ½|², a = 0.1, homogeneous Dirichlet), on a DMDA so that -snes_grid_sequence can
   refine it: the peer of nrmicp.distributed in benchmarks/distributed/bench.py. The DMDA holds
   the boundary nodes too (rows u = 0), so M grid points per direction are M − 2 interior nodes,
   the scene's m. Prints one line: dim M iterations(finest) wall-seconds CPU-seconds(slowest rank) Res. */
#include <petscdmda.h>
#include <petscsnes.h>
#include <time.h>

typedef struct { PetscInt dim; } Ctx;

static PetscReal psi_at(PetscReal x, PetscReal y, PetscReal z) {
  return 0.1 - (x - 0.5) * (x - 0.5) - (y - 0.5) * (y - 0.5) - (z - 0.5) * (z - 0.5);
}

/* F(u) = −Δ_h u inside (the 5- or 7-point stencil / h²), u on the boundary; so is its Jacobian. */
static PetscErrorCode residual(SNES snes, Vec U, Vec F, void *ptr) {
  DM da; Vec Ul; DMDALocalInfo info; PetscReal h, ih2;
  PetscFunctionBeginUser;
  PetscCall(SNESGetDM(snes, &da));
  PetscCall(DMDAGetLocalInfo(da, &info));
  h = 1.0 / (info.mx - 1); ih2 = 1.0 / (h * h);
  PetscCall(DMGetLocalVector(da, &Ul));
  PetscCall(DMGlobalToLocal(da, U, INSERT_VALUES, Ul));
  if (info.dim == 2) {
    PetscScalar **u, **f;
    PetscCall(DMDAVecGetArrayRead(da, Ul, &u)); PetscCall(DMDAVecGetArray(da, F, &f));
    for (PetscInt j = info.ys; j < info.ys + info.ym; j++)
      for (PetscInt i = info.xs; i < info.xs + info.xm; i++) {
        if (i == 0 || j == 0 || i == info.mx - 1 || j == info.my - 1) f[j][i] = u[j][i];
        else f[j][i] = ih2 * (4 * u[j][i] - u[j][i - 1] - u[j][i + 1] - u[j - 1][i] - u[j + 1][i]);
      }
    PetscCall(DMDAVecRestoreArrayRead(da, Ul, &u)); PetscCall(DMDAVecRestoreArray(da, F, &f));
  } else {
    PetscScalar ***u, ***f;
    PetscCall(DMDAVecGetArrayRead(da, Ul, &u)); PetscCall(DMDAVecGetArray(da, F, &f));
    for (PetscInt k = info.zs; k < info.zs + info.zm; k++)
      for (PetscInt j = info.ys; j < info.ys + info.ym; j++)
        for (PetscInt i = info.xs; i < info.xs + info.xm; i++) {
          if (i == 0 || j == 0 || k == 0 || i == info.mx - 1 || j == info.my - 1 || k == info.mz - 1) f[k][j][i] = u[k][j][i];
          else f[k][j][i] = ih2 * (6 * u[k][j][i] - u[k][j][i - 1] - u[k][j][i + 1] - u[k][j - 1][i] - u[k][j + 1][i]
                                   - u[k - 1][j][i] - u[k + 1][j][i]);
        }
    PetscCall(DMDAVecRestoreArrayRead(da, Ul, &u)); PetscCall(DMDAVecRestoreArray(da, F, &f));
  }
  PetscCall(DMRestoreLocalVector(da, &Ul));
  PetscFunctionReturn(0);
}

static PetscErrorCode jacobian(SNES snes, Vec U, Mat J, Mat P, void *ptr) {
  DM da; DMDALocalInfo info; PetscReal h, ih2;
  PetscFunctionBeginUser;
  PetscCall(SNESGetDM(snes, &da));
  PetscCall(DMDAGetLocalInfo(da, &info));
  h = 1.0 / (info.mx - 1); ih2 = 1.0 / (h * h);
  for (PetscInt k = info.zs; k < info.zs + (info.dim == 3 ? info.zm : 1); k++)
    for (PetscInt j = info.ys; j < info.ys + info.ym; j++)
      for (PetscInt i = info.xs; i < info.xs + info.xm; i++) {
        MatStencil row = {.k = k, .j = j, .i = i}, col[7];
        PetscScalar v[7]; PetscInt nc = 0;
        PetscBool edge = i == 0 || j == 0 || i == info.mx - 1 || j == info.my - 1 ||
                         (info.dim == 3 && (k == 0 || k == info.mz - 1));
        col[nc] = row; v[nc++] = edge ? 1.0 : 2 * info.dim * ih2;
        if (!edge) {
          const PetscInt d[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
          for (PetscInt s = 0; s < 2 * info.dim; s++) {
            col[nc].i = i + d[s][0]; col[nc].j = j + d[s][1]; col[nc].k = k + d[s][2]; col[nc].c = 0;
            v[nc++] = -ih2;
          }
        }
        PetscCall(MatSetValuesStencil(P, 1, &row, nc, col, v, INSERT_VALUES));
      }
  PetscCall(MatAssemblyBegin(P, MAT_FINAL_ASSEMBLY)); PetscCall(MatAssemblyEnd(P, MAT_FINAL_ASSEMBLY));
  PetscFunctionReturn(0);
}

/* ψ on the interior, unbounded on the boundary; computed on every grid of the sequence. */
static PetscErrorCode bounds(SNES snes, Vec lo, Vec up) {
  DM da; DMDALocalInfo info; PetscReal h;
  PetscFunctionBeginUser;
  PetscCall(SNESGetDM(snes, &da));
  PetscCall(DMDAGetLocalInfo(da, &info));
  h = 1.0 / (info.mx - 1);
  PetscCall(VecSet(up, PETSC_INFINITY));
  if (info.dim == 2) {
    PetscScalar **l;
    PetscCall(DMDAVecGetArray(da, lo, &l));
    for (PetscInt j = info.ys; j < info.ys + info.ym; j++)
      for (PetscInt i = info.xs; i < info.xs + info.xm; i++)
        l[j][i] = (i == 0 || j == 0 || i == info.mx - 1 || j == info.my - 1) ? PETSC_NINFINITY : psi_at(i * h, j * h, 0.5);
    PetscCall(DMDAVecRestoreArray(da, lo, &l));
  } else {
    PetscScalar ***l;
    PetscCall(DMDAVecGetArray(da, lo, &l));
    for (PetscInt k = info.zs; k < info.zs + info.zm; k++)
      for (PetscInt j = info.ys; j < info.ys + info.ym; j++)
        for (PetscInt i = info.xs; i < info.xs + info.xm; i++)
          l[k][j][i] = (i == 0 || j == 0 || k == 0 || i == info.mx - 1 || j == info.my - 1 || k == info.mz - 1)
                           ? PETSC_NINFINITY : psi_at(i * h, j * h, k * h);
    PetscCall(DMDAVecRestoreArray(da, lo, &l));
  }
  PetscFunctionReturn(0);
}

int main(int argc, char **argv) {
  DM da; SNES snes; Vec u, F, lo, up, m; PetscInt dim = 2, M = 17, its; PetscReal res; PetscLogDouble t0, t1, c0, c1, cpu;
  PetscCall(PetscInitialize(&argc, &argv, NULL, NULL));
  PetscCall(PetscOptionsGetInt(NULL, NULL, "-dim", &dim, NULL));
  PetscCall(PetscOptionsGetInt(NULL, NULL, "-M", &M, NULL));  /* points of the first (coarsest) grid */
  if (dim == 2) PetscCall(DMDACreate2d(PETSC_COMM_WORLD, DM_BOUNDARY_NONE, DM_BOUNDARY_NONE, DMDA_STENCIL_STAR, M, M,
                                       PETSC_DECIDE, PETSC_DECIDE, 1, 1, NULL, NULL, &da));
  else PetscCall(DMDACreate3d(PETSC_COMM_WORLD, DM_BOUNDARY_NONE, DM_BOUNDARY_NONE, DM_BOUNDARY_NONE, DMDA_STENCIL_STAR,
                              M, M, M, PETSC_DECIDE, PETSC_DECIDE, PETSC_DECIDE, 1, 1, NULL, NULL, NULL, &da));
  PetscCall(DMSetFromOptions(da)); PetscCall(DMSetUp(da));
  PetscCall(SNESCreate(PETSC_COMM_WORLD, &snes));
  PetscCall(SNESSetDM(snes, da));
  PetscCall(SNESSetType(snes, SNESVINEWTONRSLS));
  PetscCall(DMSNESSetFunction(da, residual, NULL));
  PetscCall(DMSNESSetJacobian(da, jacobian, NULL));
  PetscCall(SNESVISetComputeVariableBounds(snes, bounds));
  PetscCall(SNESSetFromOptions(snes));
  PetscCall(DMCreateGlobalVector(da, &u)); PetscCall(VecSet(u, 0.0));
  PetscCall(PetscTime(&t0)); c0 = (PetscLogDouble)clock() / CLOCKS_PER_SEC;
  PetscCall(SNESSolve(snes, NULL, u));
  PetscCall(PetscTime(&t1)); c1 = (PetscLogDouble)clock() / CLOCKS_PER_SEC;
  cpu = c1 - c0;
  PetscCallMPI(MPI_Allreduce(MPI_IN_PLACE, &cpu, 1, MPI_DOUBLE, MPI_MAX, PETSC_COMM_WORLD));
  PetscCall(SNESGetIterationNumber(snes, &its));
  PetscCall(SNESGetSolution(snes, &u));
  PetscCall(SNESGetDM(snes, &da));
  /* Res = ‖min(F(u), u − ψ)‖ on the interior (the boundary rows are 0 at the solution). */
  PetscCall(VecDuplicate(u, &F)); PetscCall(VecDuplicate(u, &lo)); PetscCall(VecDuplicate(u, &up)); PetscCall(VecDuplicate(u, &m));
  PetscCall(residual(snes, u, F, NULL));
  PetscCall(bounds(snes, lo, up));
  PetscCall(VecWAXPY(m, -1.0, lo, u));
  PetscCall(VecPointwiseMin(m, m, F));
  PetscCall(VecNorm(m, NORM_2, &res));
  {
    DMDALocalInfo info;
    PetscCall(DMDAGetLocalInfo(da, &info));
    PetscCall(PetscPrintf(PETSC_COMM_WORLD, "RESULT %d %d %d %.6f %.6f %.3e\n", (int)dim, (int)info.mx, (int)its, t1 - t0, cpu, res));
  }
  PetscCall(VecDestroy(&F)); PetscCall(VecDestroy(&lo)); PetscCall(VecDestroy(&up)); PetscCall(VecDestroy(&m));
  PetscCall(SNESDestroy(&snes));
  PetscCall(PetscFinalize());
  return 0;
}
