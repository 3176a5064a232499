!> Test hooks of the pressure operator: the extension _cpdi_test (cpdi_test.pyf), which the tests
!> import and the memcheck driver calls; built with the core but never installed (docs/design.md).
module cpdi_test_hooks
  !! Stand-alone staggered test grids (no simulation, no handle): y = A x, z = M^-1 r and the
  !! projection of a face field, for tests/test_incompressible.py and tests/test_multigrid.py.
  !! Same conventions as cpdi_api: explicit-shape arrays, ierr and a message, no stop.
  use, intrinsic :: iso_c_binding, only: c_double, c_int
  use cpdi_kinds, only: wp
  use cpdi_status, only: status_t, MSG_LEN, CPDI_ERR_INPUT, CPDI_ERR_SOLVE, finish => status_finish
  use cpdi_pressure, only: mac_t, mac_alloc, mac_walls, mac_assemble, mac_apply, mac_solve, mac_project, CELL_FLUID, &
                           mac_precondition, PRECOND_MIC0, PRECOND_MULTIGRID
  implicit none
  private

  public :: cpdi_poisson_apply, cpdi_poisson_precond, cpdi_poisson_project

contains

  subroutine test_mac(mc, nx, ny, cell, fill, h, st)
    !! A stand-alone staggered grid of nx x ny cells whose outer ring is boundary (its
    !! kinds given in cell); for the tests of the pressure operator and projection.
    type(mac_t), intent(inout) :: mc
    integer(c_int), intent(in) :: nx, ny
    integer(c_int), intent(in) :: cell(nx*ny)
    real(c_double), intent(in) :: fill(nx*ny), h
    type(status_t), intent(inout) :: st
    if (nx < 3 .or. ny < 3 .or. .not. (h > 0.0_wp)) then
      call st%set(CPDI_ERR_INPUT, 'the test grid needs nx, ny >= 3 and h > 0')
      return
    end if
    if (any(cell < 0) .or. any(cell > 2)) then
      call st%set(CPDI_ERR_INPUT, 'cell kinds are 0 (air), 1 (water), 2 (wall)')
      return
    end if
    call mac_alloc(mc, [nx, ny], [2, 2], [nx - 1, ny - 1], h, st)
    if (.not. st%ok()) return
    mc%cell = cell
    mc%fill = fill
  end subroutine test_mac


  subroutine cpdi_poisson_apply(nx, ny, cell, fill, x, y, ierr, msg)
    !! y = A x: the pressure operator (5-point, ghost-fluid surface) on a test grid (h = 1).
    integer(c_int), intent(in) :: nx, ny
    integer(c_int), intent(in) :: cell(nx*ny)
    real(c_double), intent(in) :: fill(nx*ny), x(nx*ny)
    real(c_double), intent(out) :: y(nx*ny)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(mac_t) :: mc
    y = 0.0_wp
    call test_mac(mc, nx, ny, cell, fill, 1.0_wp, st)
    if (st%ok()) then
      call mac_assemble(mc, 1.0_wp, 1.0_wp, 0.0_wp)
      call mac_apply(mc, x, y)
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_poisson_apply


  subroutine cpdi_poisson_precond(nx, ny, cell, fill, precond, r, z, ierr, msg)
    !! z = M^-1 r: the CG's preconditioner precond (0 mic0, 1 multigrid) for the pressure operator
    !! of a test grid (h = 1, as cpdi_poisson_apply), on its water cells (0 elsewhere).
    integer(c_int), intent(in) :: nx, ny, precond
    integer(c_int), intent(in) :: cell(nx*ny)
    real(c_double), intent(in) :: fill(nx*ny), r(nx*ny)
    real(c_double), intent(out) :: z(nx*ny)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(mac_t) :: mc
    z = 0.0_wp
    if (precond /= PRECOND_MIC0 .and. precond /= PRECOND_MULTIGRID) &
      call st%set(CPDI_ERR_INPUT, 'precond must be 0 (mic0) or 1 (multigrid)')
    if (st%ok()) call test_mac(mc, nx, ny, cell, fill, 1.0_wp, st)
    if (st%ok()) then
      mc%precond = precond
      call mac_assemble(mc, 1.0_wp, 1.0_wp, 0.0_wp)
      mc%r = 0.0_wp
      where (mc%cell == CELL_FLUID) mc%r = r
      call mac_precondition(mc, .true.)
      z = mc%z
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_poisson_precond


  subroutine cpdi_poisson_project(nx, ny, cell, fill, u, v, dt, rho, h, beta, tol, maxit, precond, p, uo, vo, &
                                  iters, resid, defect, nclosed, ierr, msg)
    !! Project the face field (u, v) of a test grid: solve for p with the preconditioner precond
    !! (0 mic0, 1 multigrid), return the projected faces uo, vo (unchanged where no water is
    !! adjacent), CG iterations and residual, and the closed water regions' null-space defect
    !! of the right-hand side and their count (cpdi_pressure).
    integer(c_int), intent(in) :: nx, ny, maxit, precond
    integer(c_int), intent(in) :: cell(nx*ny)
    real(c_double), intent(in) :: fill(nx*ny), u(nx*ny), v(nx*ny), dt, rho, h, beta, tol
    real(c_double), intent(out) :: p(nx*ny), uo(nx*ny), vo(nx*ny), resid, defect
    integer(c_int), intent(out) :: iters, nclosed
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(mac_t) :: mc
    logical :: converged
    character(len=200) :: buf
    p = 0.0_wp
    uo = u
    vo = v
    iters = 0
    resid = 0.0_wp
    defect = 0.0_wp
    nclosed = 0
    if (precond /= PRECOND_MIC0 .and. precond /= PRECOND_MULTIGRID) &
      call st%set(CPDI_ERR_INPUT, 'precond must be 0 (mic0) or 1 (multigrid)')
    if (st%ok()) call test_mac(mc, nx, ny, cell, fill, h, st)
    if (st%ok()) then
      mc%precond = precond
      mc%u = u
      mc%v = v
      call mac_walls(mc)
      call mac_assemble(mc, dt, rho, beta)
      call mac_solve(mc, tol, maxit, converged)
      iters = mc%iters
      resid = mc%resid
      defect = mc%defect
      nclosed = mc%nfloat
      if (.not. converged) then
        write (buf, '(a,es10.3,a,i0,a)') 'the pressure solve did not converge (relative residual ', mc%resid, &
          ' after ', mc%iters, ' CG iterations); raise maxit or tol'
        call st%set(CPDI_ERR_SOLVE, trim(buf))
      else
        call mac_project(mc, dt, rho)
        p = mc%p
        uo = mc%u
        vo = mc%v
      end if
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_poisson_project

end module cpdi_test_hooks
