!> Fortran-only driver for `make memcheck`: a small water column with an elastic block in
!> contact and the projection on, through the same API Python uses, plus the error paths; the
!> same water column incompressible, with its face-velocity and cell-pressure queries; the block
!> alone with contact on (one velocity field); the test hooks' grid checks (cpdi_test_hooks).
!> Built with -fsanitize=address and the debug flags; any invalid access or leak fails it.
program memcheck_driver
  use, intrinsic :: iso_c_binding, only: c_int, c_double
  use cpdi_api
  use cpdi_test_hooks, only: cpdi_poisson_project
  implicit none
  integer(c_int) :: h, ierr, nsteps, n, i, j, k, nb, nw
  character(len=512) :: msg
  real(c_double) :: t, dx, tdef
  integer(c_int) :: ncl
  real(c_double), allocatable :: x(:, :), v(:, :), m(:), vol(:), r(:, :), xo(:, :), vo(:, :), f(:, :), s(:, :), &
                                 volo(:), ro(:, :)
  integer(c_int), allocatable :: mat(:), body(:)
  real(c_double) :: props(8, 2)
  integer :: failures
  integer(c_int) :: nprow, nscal
  real(c_double), allocatable :: ps(:, :), ss(:)
  real(c_double), allocatable :: fu(:, :), fv(:, :), cp(:, :), cf(:, :), ft(:, :), vt(:, :)
  integer(c_int), allocatable :: ck(:, :), gi(:, :), gmask(:)
  integer(c_int) :: gmask2(1, 1)
  real(c_double) :: p11(1, 1), f11(1, 1), p4(4), u4(4), v4(4), p6(6), u6(6), v6(6)
  real(c_double), allocatable :: gs(:, :), gw(:, :), ggx(:, :), ggy(:, :), gval(:), fa(:, :), fb(:, :)
  real(c_double) :: info6(6)

  failures = 0
  dx = 0.01_c_double
  n = 0
  nb = 0
  allocate (x(2, 400), v(2, 400), m(400), vol(400), r(4, 400), mat(400), body(400))
  do j = 1, 16
    do i = 1, 10
      n = n + 1
      x(:, n) = [0.005_c_double + (i - 1)*dx, 0.005_c_double + (j - 1)*dx]
      mat(n) = 1
      body(n) = 1
    end do
  end do
  do j = 1, 4
    do i = 1, 4
      n = n + 1
      x(:, n) = [0.2_c_double + (i - 1)*dx, 0.005_c_double + (j - 1)*dx]
      mat(n) = 2
      body(n) = 2
    end do
  end do
  v(:, 1:n) = 0.0_c_double
  vol(1:n) = dx*dx
  m(1:n) = merge(1000.0_c_double, 1200.0_c_double, mat(1:n) == 1)*vol(1:n)
  do k = 1, n
    r(:, k) = [0.5_c_double*dx, 0.0_c_double, 0.0_c_double, 0.5_c_double*dx]
  end do
  props = 0.0_c_double
  props(:, 1) = [1000.0_c_double, 0.0_c_double, 0.0_c_double, 2.0e5_c_double, 1.0e-3_c_double, 0.0_c_double, &
                 0.0_c_double, 1.0_c_double]
  props(:, 2) = [1200.0_c_double, 1.0e6_c_double, 0.3_c_double, 0.0_c_double, 0.0_c_double, 0.0_c_double, &
                 0.0_c_double, 0.0_c_double]

  call cpdi_new(h, ierr, msg); call expect_ok('new')
  call cpdi_set_grid(h, [0.0_c_double, 0.0_c_double], [40_c_int, 20_c_int], 0.01_c_double, [1, 1, 1, 0], &
                     ierr, msg); call expect_ok('grid')
  call cpdi_set_materials(h, 2, [2_c_int, 1_c_int], props, ierr, msg); call expect_ok('materials')
  call cpdi_set_particles(h, n, x(:, 1:n), v(:, 1:n), m(1:n), vol(1:n), r(:, 1:n), mat(1:n), ierr, msg)
  call expect_ok('particles')
  call cpdi_set_bodies(h, n, body(1:n), 1, 0.2_c_double, 0.9_c_double, ierr, msg); call expect_ok('bodies')
  call options(1, 1, 0, 0.3_c_double, 0.0_c_double, 0.0_c_double, 'options')
  call cpdi_advance(h, 0.05_c_double, 200, 1, nsteps, t, ierr, msg); call expect_ok('advance')
  allocate (xo(2, n), vo(2, n), f(4, n), s(4, n), volo(n), ro(4, n))
  call cpdi_get_state(h, n, xo, vo, f, s, volo, ro, ierr, msg); call expect_ok('state')
  ! nodal projection path
  call options(2, 0, 0, 0.3_c_double, 0.0_c_double, 0.1_c_double, 'options nodal')
  call cpdi_advance(h, 0.06_c_double, 50, 1, nsteps, t, ierr, msg); call expect_ok('advance nodal')
  ! checkpoint round trip: full state out, back in, step on; a damaged state is refused
  call cpdi_full_state_size(nprow, nscal, ierr, msg); call expect_ok('full state size')
  allocate (ps(nprow, n), ss(nscal))
  call cpdi_get_full_state(h, nprow, n, nscal, ps, ss, ierr, msg); call expect_ok('get full state')
  call cpdi_set_full_state(h, nprow, n, nscal, ps, ss, ierr, msg); call expect_ok('set full state')
  call cpdi_advance(h, 0.065_c_double, 20, 1, nsteps, t, ierr, msg); call expect_ok('advance after restore')
  ss(1) = -1.0_c_double
  call cpdi_set_full_state(h, nprow, n, nscal, ps, ss, ierr, msg); call expect_error('negative time')
  call cpdi_get_full_state(h, nprow, n - 1, nscal, ps(:, 1:n - 1), ss, ierr, msg); call expect_error('wrong n')
  deallocate (ps, ss)
  ! error paths must return cleanly
  call cpdi_set_grid(h, [0.0_c_double, 0.0_c_double], [40_c_int, 20_c_int], 0.0_c_double, [1, 1, 1, 0], ierr, msg)
  call expect_error('zero cell size')
  call options(0, 0, 1, 0.3_c_double, 1.0_c_double, 0.0_c_double, 'options fixed dt')
  call cpdi_advance(h, 1.0_c_double, 5, 1, nsteps, t, ierr, msg); call expect_error('unstable fixed dt')
  call cpdi_free(h, ierr, msg); call expect_ok('free')
  call cpdi_advance(h, 1.0_c_double, 5, 1, nsteps, t, ierr, msg); call expect_error('freed handle')
  ! every routine whose checks read the simulation after the lookup: a freed handle is an error,
  ! not a read through a null pointer (Fortran need not short-circuit .and.; -O0 does not)
  allocate (gs(4, 1), gw(4, 1), ggx(4, 1), ggy(4, 1), gi(4, 1), gval(1), gmask(1), fa(2, 1), fb(1, 2))
  gmask = 1
  gval = 0.0_c_double
  call cpdi_set_bodies(h, 1, [1_c_int], 0, 0.0_c_double, 0.9_c_double, ierr, msg); call expect_error('freed bodies')
  call cpdi_set_state(h, 1, vo(:, 1:1), f(:, 1:1), 0.0_c_double, ierr, msg); call expect_error('freed state')
  call cpdi_set_body_force(h, 1, vo(:, 1:1), ierr, msg); call expect_error('freed body force')
  call cpdi_get_state(h, 1, xo(:, 1:1), vo(:, 1:1), f(:, 1:1), s(:, 1:1), volo(1:1), ro(:, 1:1), ierr, msg)
  call expect_error('freed get state')
  call cpdi_face_velocity(h, 1, 1, fa, fb, ierr, msg); call expect_error('freed face velocity')
  call cpdi_grid_pressure(h, 1, 1, p11, f11, gmask2, ierr, msg)
  call expect_error('freed grid pressure')
  call cpdi_transfer_cycle(h, ierr, msg); call expect_error('freed transfer cycle')
  call cpdi_grid_info(h, info6, ierr, msg); call expect_error('freed grid info')
  call cpdi_get_shape(h, 1, 4, gi, gw, ggx, ggy, ierr, msg); call expect_error('freed shape')
  call cpdi_project(h, 1, 1, gmask, gval, ierr, msg); call expect_error('freed project')
  deallocate (gs, gw, ggx, ggy, gi, gval, gmask, fa, fb)
  ! the water column alone, incompressible: a few steps and the grid queries
  nw = 160
  call cpdi_new(h, ierr, msg); call expect_ok('new incompressible')
  call cpdi_set_grid(h, [0.0_c_double, 0.0_c_double], [40_c_int, 20_c_int], 0.01_c_double, [1, 1, 1, 0], &
                     ierr, msg); call expect_ok('grid incompressible')
  call cpdi_set_materials(h, 1, [2_c_int], props(:, 1:1), ierr, msg); call expect_ok('materials incompressible')
  call cpdi_set_particles(h, nw, x(:, 1:nw), v(:, 1:nw), m(1:nw), vol(1:nw), r(:, 1:nw), mat(1:nw), ierr, msg)
  call expect_ok('particles incompressible')
  call options(0, 0, 0, 0.5_c_double, 0.0_c_double, 0.0_c_double, 'options incompressible')
  call cpdi_set_option(h, 'fluid', 1, [1.0_c_double], ierr, msg); call expect_ok('fluid incompressible')
  call cpdi_set_option(h, 'pressure_precond', 1, [0.0_c_double], ierr, msg); call expect_ok('mic0 preconditioner')
  call cpdi_advance(h, 0.025_c_double, 10, 1, nsteps, t, ierr, msg); call expect_ok('advance incompressible')
  call cpdi_set_option(h, 'pressure_precond', 1, [1.0_c_double], ierr, msg); call expect_ok('multigrid preconditioner')
  call cpdi_advance(h, 0.05_c_double, 20, 1, nsteps, t, ierr, msg); call expect_ok('advance incompressible, multigrid')
  allocate (fu(41, 20), fv(40, 21), cp(40, 20), cf(40, 20), ck(40, 20))
  call cpdi_face_velocity(h, 40, 20, fu, fv, ierr, msg); call expect_ok('face velocity')
  call cpdi_grid_pressure(h, 40, 20, cp, cf, ck, ierr, msg); call expect_ok('grid pressure')
  call cpdi_free(h, ierr, msg); call expect_ok('free incompressible')
  ! the test grid's own checks (Python's wrapper refuses short grids before the call; a Fortran
  ! caller has only these): a grid short both ways, or with no positive cell size, is an error
  call cpdi_poisson_project(2, 2, [(2_c_int, k = 1, 4)], [(0.0_c_double, k = 1, 4)], [(0.0_c_double, k = 1, 4)], &
                            [(0.0_c_double, k = 1, 4)], 0.01_c_double, 1000.0_c_double, 1.0_c_double, 0.0_c_double, &
                            1.0e-12_c_double, 10, 0, p4, u4, v4, nsteps, t, tdef, ncl, ierr, msg)
  call expect_error('test grid short both ways')
  call cpdi_poisson_project(2, 3, [(2_c_int, k = 1, 6)], [(0.0_c_double, k = 1, 6)], [(0.0_c_double, k = 1, 6)], &
                            [(0.0_c_double, k = 1, 6)], 0.01_c_double, 1000.0_c_double, 1.0_c_double, 0.0_c_double, &
                            1.0e-12_c_double, 10, 0, p6, u6, v6, nsteps, t, tdef, ncl, ierr, msg)
  call expect_error('test grid short in x')
  ! the elastic block alone with contact on: one body, one velocity field, the walls under the
  ! volume constraint (their volumes were once read out of bounds for a single field)
  call cpdi_new(h, ierr, msg); call expect_ok('new one body')
  call cpdi_set_grid(h, [0.0_c_double, 0.0_c_double], [40_c_int, 20_c_int], 0.01_c_double, [1, 1, 1, 0], &
                     ierr, msg); call expect_ok('grid one body')
  call cpdi_set_materials(h, 2, [2_c_int, 1_c_int], props, ierr, msg); call expect_ok('materials one body')
  call cpdi_set_particles(h, n - nw, x(:, nw + 1:n), v(:, nw + 1:n), m(nw + 1:n), vol(nw + 1:n), r(:, nw + 1:n), &
                          mat(nw + 1:n), ierr, msg); call expect_ok('particles one body')
  call cpdi_set_bodies(h, n - nw, [(1_c_int, k = nw + 1, n)], 1, 0.0_c_double, 0.9_c_double, ierr, msg)
  call expect_ok('bodies one body')
  call options(0, 0, 0, 0.3_c_double, 0.0_c_double, 0.0_c_double, 'options one body')
  call cpdi_advance(h, 0.01_c_double, 20, 1, nsteps, t, ierr, msg); call expect_ok('advance one body')
  call cpdi_free(h, ierr, msg); call expect_ok('free one body')
  ! a state whose signal speed is not finite (a speed that overflows), refused when it is
  ! first prepared, in a run that never used the projection
  call cpdi_new(h, ierr, msg); call expect_ok('new overflow')
  call cpdi_set_grid(h, [0.0_c_double, 0.0_c_double], [40_c_int, 20_c_int], 0.01_c_double, [1, 1, 1, 0], &
                     ierr, msg); call expect_ok('grid overflow')
  call cpdi_set_materials(h, 2, [2_c_int, 1_c_int], props, ierr, msg); call expect_ok('materials overflow')
  call cpdi_set_particles(h, n, x(:, 1:n), v(:, 1:n), m(1:n), vol(1:n), r(:, 1:n), mat(1:n), ierr, msg)
  call expect_ok('particles overflow')
  allocate (vt(2, n), ft(4, n))
  vt = 0.0_c_double
  vt(1, n) = 1.0e200_c_double
  do k = 1, n
    ft(:, k) = [1.0_c_double, 0.0_c_double, 0.0_c_double, 1.0_c_double]
  end do
  call cpdi_set_state(h, n, vt, ft, 0.0_c_double, ierr, msg); call expect_ok('state overflow')
  call cpdi_stable_dt(h, t, ierr, msg); call expect_error('speed that overflows')
  call cpdi_free(h, ierr, msg); call expect_ok('free overflow')
  deallocate (x, v, m, vol, r, mat, body, xo, vo, f, s, volo, ro, fu, fv, cp, cf, ck, vt, ft)
  print '(a,i0,a)', 'memcheck driver: ', failures, ' failures'
  if (failures > 0) call exit(1)

contains

  subroutine options(projection, domain_scaling, fixed_dt, cfl, dt, pstab, what)
    !! The options of a run by name (cpdi_options' table): cpdi shape, musl, log kinematics,
    !! gravity -9.81 m/s^2, flip 1, lcrit 0.49999, no damping; the rest as given.
    integer, intent(in) :: projection, domain_scaling, fixed_dt
    real(c_double), intent(in) :: cfl, dt, pstab
    character(len=*), intent(in) :: what
    call set1('shape', 2.0_c_double, what)
    call set1('update', 1.0_c_double, what)
    call set1('projection', real(projection, c_double), what)
    call set1('kinematics', 0.0_c_double, what)
    call set1('domain_scaling', real(domain_scaling, c_double), what)
    call set1('fixed_dt', real(fixed_dt, c_double), what)
    call set1('cfl', cfl, what)
    call cpdi_set_option(h, 'gravity', 2, [0.0_c_double, -9.81_c_double], ierr, msg); call expect_ok(what//': gravity')
    call set1('damping', 0.0_c_double, what)
    call set1('dt', dt, what)
    call set1('flip', 1.0_c_double, what)
    call set1('lcrit', 0.49999_c_double, what)
    call set1('projection_stabilization', pstab, what)
    call cpdi_check_options(h, ierr, msg); call expect_ok(what)
  end subroutine options

  subroutine set1(name, value, what)
    !! One scalar option by name, expected to be accepted.
    character(len=*), intent(in) :: name, what
    real(c_double), intent(in) :: value
    call cpdi_set_option(h, name, 1, [value], ierr, msg); call expect_ok(what//': '//name)
  end subroutine set1

  subroutine expect_ok(what)
    character(len=*), intent(in) :: what
    if (ierr /= 0) then
      failures = failures + 1
      print '(3a)', what, ': unexpected error: ', trim(msg)
    end if
  end subroutine expect_ok

  subroutine expect_error(what)
    character(len=*), intent(in) :: what
    if (ierr == 0) then
      failures = failures + 1
      print '(2a)', what, ': expected an error, got none'
    end if
  end subroutine expect_error
end program memcheck_driver
