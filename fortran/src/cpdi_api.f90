!> Flat, f2py-facing API: the production interface of the extension _cpdi (harness.solver).
module cpdi_api
  !! Every routine takes explicit-shape `real(c_double)` / `integer(c_int)` arrays and
  !! returns `ierr` (0 = success, otherwise a CPDI_ERR_* code) and a message naming the
  !! problem and the fix. Simulations live in a registry addressed by integer handles,
  !! so several can coexist in one Python process. Nothing here stops the process.
  !! Production only: the tests' stand-alone pressure-operator hooks are in the extension
  !! _cpdi_test (fortran/tests/cpdi_test_hooks.f90) and the bench's core round-trip probe in
  !! _cpdi_bench (fortran/bench/cpdi_bench_probe.f90); neither is installed (docs/design.md).
  use, intrinsic :: iso_c_binding, only: c_double, c_int
  use cpdi_kinds, only: wp, ik
  use cpdi_slots, only: DIAG_MASS, NPSTATE, NSSTATE, ROW_X, ROW_V, ROW_F, ROW_L, ROW_SIG, ROW_R, ROW_BF, ROW_VOL, &
                        ROW_PSI, ROW_JBAR, ROW_AW, NROWFIELD, ROW_NAMES, ROW_FIRST, SCAL_T, SCAL_STEPS, SCAL_SMAX, &
                        SCAL_VISC_DT, SCAL_DT_LAST, NSCALAR, SCALAR_NAMES, DIAG_NAMES, TIMER_NAMES, SLOT_NAME_LEN
  use cpdi_status, only: status_t, MSG_LEN, CPDI_ERR_INPUT, CPDI_ERR_HANDLE, CPDI_ERR_STATE, CPDI_ERR_LAPACK, &
                         finish => status_finish
  use cpdi_grid, only: grid_init, GRID_PAD
  use cpdi_particles, only: particles_alloc
  use cpdi_shape, only: shape_count, shape_slot
  use cpdi_materials, only: material_init, NMATPROP, MAT_RIGID, MAT_FLUID
  use cpdi_kinematics, only: log_strain, log_strain_lapack, det2, map_domains
  use cpdi_projection, only: projection_alloc, project_scalar
  use cpdi_sim, only: sim_t, NDIAG, NTIMER, sim_apply_options
  use cpdi_options, only: OPTIONS, NOPT, OPT_NAME_LEN, OPT_CHOICE_LEN, OPT_UNIT_LEN, OPT_HELP_LEN, opt_set, opt_check
  use cpdi_motion, only: vtable_set
  use cpdi_step, only: sim_prepare, sim_step, sim_stable_dt, sim_check_inside, sim_release
  use cpdi_incompressible, only: incomp_transfer_cycle, FLUID_INCOMPRESSIBLE
  use cpdi_pressure, only: CELL_FLUID, CELL_SOLID
  implicit none
  private

  type :: slot_t
    logical :: used = .false.
    type(sim_t), allocatable :: s
  end type slot_t

  type(slot_t), allocatable, target, save :: reg(:)

  public :: cpdi_new, cpdi_free, cpdi_set_grid, cpdi_set_materials, cpdi_set_particles, &
            cpdi_set_body_force, cpdi_advance, cpdi_get_state, cpdi_get_diag, &
            cpdi_get_timers, cpdi_get_shape, cpdi_grid_info, cpdi_log_strain, cpdi_stable_dt, &
            cpdi_set_state, cpdi_project, cpdi_set_bodies, cpdi_threads
  ! Incompressible water (issue 20): named options, the grid pressure, the face lattices.
  public :: cpdi_solid_force, cpdi_face_velocity, cpdi_rigid_bodies
  ! Water entry (issue 40): velocity tables of prescribed rigid bodies, the water's load per particle.
  public :: cpdi_set_velocity_table, cpdi_water_loads
  public :: cpdi_set_option, cpdi_grid_pressure, cpdi_transfer_cycle, cpdi_pressure_stats
  ! Every option by name through one table (issue 39 item 1).
  public :: cpdi_check_options, cpdi_option_count, cpdi_option_info
  ! The names of the diagnostics, timers and full-state rows (cpdi_slots).
  public :: cpdi_slot_count, cpdi_slot_info

  ! Checkpoint and restart (issue 8): the full internal state as flat arrays.
  public :: cpdi_full_state_size, cpdi_get_full_state, cpdi_set_full_state

contains

  subroutine lookup(handle, s, st)
    !! Resolve a handle to its simulation; s is null when st reports an error. Callers test
    !! st%ok() in an if of its own before touching s: Fortran need not short-circuit `.and.`,
    !! and gfortran at -O0 evaluates both operands (a freed handle then read through null).
    integer(c_int), intent(in) :: handle
    type(sim_t), pointer, intent(out) :: s
    type(status_t), intent(inout) :: st
    character(len=120) :: buf
    s => null()
    if (.not. allocated(reg)) then
      call st%set(CPDI_ERR_HANDLE, 'no simulation exists; create one with cpdi_new')
      return
    end if
    if (handle < 1 .or. handle > size(reg)) then
      write (buf, '(a,i0,a)') 'simulation handle ', handle, ' is not valid; create one with cpdi_new'
      call st%set(CPDI_ERR_HANDLE, trim(buf))
      return
    end if
    if (.not. reg(handle)%used) then
      write (buf, '(a,i0,a)') 'simulation handle ', handle, ' was freed; create a new one'
      call st%set(CPDI_ERR_HANDLE, trim(buf))
      return
    end if
    s => reg(handle)%s
  end subroutine lookup

  logical function finite_all(a)
    real(c_double), intent(in) :: a(:)
    finite_all = all(abs(a) <= huge(1.0_wp))   ! false for NaN and Inf
  end function finite_all

  subroutine cpdi_new(handle, ierr, msg)
    !! Create an empty simulation and return its handle.
    integer(c_int), intent(out) :: handle
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(slot_t), allocatable :: tmp(:)
    integer :: i
    type(status_t) :: st
    if (.not. allocated(reg)) allocate (reg(8))
    handle = 0
    do i = 1, size(reg)
      if (.not. reg(i)%used) then
        handle = i
        exit
      end if
    end do
    if (handle == 0) then
      allocate (tmp(2*size(reg)))
      do i = 1, size(reg)
        tmp(i)%used = reg(i)%used
        if (allocated(reg(i)%s)) call move_alloc(reg(i)%s, tmp(i)%s)
      end do
      handle = size(reg) + 1
      call move_alloc(tmp, reg)
    end if
    allocate (reg(handle)%s)
    call sim_apply_options(reg(handle)%s)   ! the option table's defaults (cpdi_options)
    reg(handle)%used = .true.
    call finish(st, ierr, msg)
  end subroutine cpdi_new

  subroutine cpdi_free(handle, ierr, msg)
    !! Release a simulation and all its memory.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) then
      call sim_release(reg(handle)%s)
      deallocate (reg(handle)%s)
      reg(handle)%used = .false.
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_free

  subroutine cpdi_set_grid(handle, origin, ncell, h, walls, ierr, msg)
    !! Define the background grid: origin [m], cells per direction, cell size [m],
    !! walls (left, right, bottom, top) as 0 open, 1 slip, 2 noslip.
    integer(c_int), intent(in) :: handle
    real(c_double), intent(in) :: origin(2)
    integer(c_int), intent(in) :: ncell(2)
    real(c_double), intent(in) :: h
    integer(c_int), intent(in) :: walls(4)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) then
      call grid_init(s%g, origin, ncell, h, walls, st)
      s%has_grid = st%ok()
      s%smax = -1.0_wp
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_grid

  subroutine cpdi_set_materials(handle, nmat, model, props, ierr, msg)
    !! Define nmat materials. model: 1 hencky, 2 newtonian_fluid, 3 rigid, 4 neo_hookean.
    !! props(:, m) = [density, youngs_modulus, poisson_ratio, bulk_modulus, viscosity, vx, vy, project (0/1)].
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: nmat
    integer(c_int), intent(in) :: model(nmat)
    real(c_double), intent(in) :: props(NMATPROP, nmat)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: m
    call lookup(handle, s, st)
    if (st%ok() .and. nmat < 1) call st%set(CPDI_ERR_INPUT, 'at least one material is needed')
    if (st%ok()) then
      if (allocated(s%mats)) deallocate (s%mats, s%rigid, s%fluid)
      if (allocated(s%vtab)) deallocate (s%vtab)   ! velocity tables belong to the materials they replace
      allocate (s%mats(nmat), s%rigid(nmat), s%fluid(nmat))
      do m = 1, nmat
        call material_init(s%mats(m), model(m), props(:, m), m, st)
        s%rigid(m) = model(m) == MAT_RIGID
        s%fluid(m) = model(m) == MAT_FLUID
      end do
      s%any_rigid = any(s%rigid)
      s%has_materials = st%ok()
      s%smax = -1.0_wp
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_materials

  subroutine cpdi_set_particles(handle, n, x, v, mass, vol, r, mat, ierr, msg)
    !! Define n particles: position x(2,n) [m], velocity v(2,n) [m/s], mass [kg/m],
    !! volume (area) [m^2], CPDI domain vectors r(4,n) = [r1x, r1y, r2x, r2y] [m] and
    !! 1-based material index. F starts at I and stress at zero.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n
    real(c_double), intent(in) :: x(2, n), v(2, n), mass(n), vol(n), r(4, n)
    integer(c_int), intent(in) :: mat(n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: ip
    character(len=200) :: buf
    call lookup(handle, s, st)
    if (st%ok() .and. n < 1) call st%set(CPDI_ERR_INPUT, 'at least one particle is needed')
    if (st%ok()) then
      if (.not. (finite_all(reshape(x, [2*n])) .and. finite_all(reshape(v, [2*n])) .and. &
                 finite_all(reshape(r, [4*n])))) then
        call st%set(CPDI_ERR_INPUT, 'particle positions, velocities or domains contain NaN or Inf; '// &
                    'give finite values')
      else if (.not. (all(mass > 0.0_wp) .and. finite_all(mass))) then
        ip = findloc(.not. (mass > 0.0_wp .and. mass <= huge(1.0_wp)), .true., 1)
        write (buf, '(a,i0,a,es11.3,a)') 'particle ', ip, ' has mass ', mass(ip), &
          '; masses must be positive and finite (check density and volume)'
        call st%set(CPDI_ERR_INPUT, trim(buf))
      else if (.not. (all(vol > 0.0_wp) .and. finite_all(vol))) then
        ip = findloc(.not. (vol > 0.0_wp .and. vol <= huge(1.0_wp)), .true., 1)
        write (buf, '(a,i0,a,es11.3,a)') 'particle ', ip, ' has volume ', vol(ip), &
          '; volumes must be positive and finite'
        call st%set(CPDI_ERR_INPUT, trim(buf))
      else if (any(.not. domain_ok(r))) then
        ip = findloc(domain_ok(r), .false., 1)
        write (buf, '(a,i0,a)') 'particle ', ip, ' has a degenerate or inverted domain (r1 x r2 <= 0); '// &
          'give r1, r2 counter-clockwise with positive area'
        call st%set(CPDI_ERR_INPUT, trim(buf))
      end if
    end if
    if (st%ok()) then
      call particles_alloc(s%p, n, st)
      if (st%ok()) then
        s%p%x = x
        s%p%v = v
        s%p%m = mass
        s%p%vol0 = vol
        s%p%vol = vol
        s%p%r0 = r
        s%p%r = r
        s%p%mat = mat
        s%t = 0.0_wp
        s%steps = 0
        s%diag = 0.0_wp
        s%diag(DIAG_MASS) = sum(mass)
        s%timers = 0.0_wp
        s%smax = -1.0_wp
        if (allocated(s%body)) deallocate (s%body)
        s%has_particles = .true.
      end if
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_particles

  subroutine cpdi_set_bodies(handle, n, body, contact, friction, fullness, ierr, msg)
    !! Body index of every particle (1-based) and the contact model: contact = 0, one
    !! velocity field for all (single continuum); 1, Bardenhagen multi-velocity-field
    !! contact between bodies with Coulomb coefficient friction, active at nodes whose
    !! support the bodies fill to at least `fullness` (fraction of h^2).
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n
    integer(c_int), intent(in) :: body(n)
    integer(c_int), intent(in) :: contact
    real(c_double), intent(in) :: friction, fullness
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok() .and. .not. (fullness >= 0.0_wp .and. fullness <= 1.0_wp)) &
      call st%set(CPDI_ERR_INPUT, 'contact fullness must lie in [0, 1] (fraction of a cell)')
    if (st%ok()) then
      if (.not. s%has_particles) call st%set(CPDI_ERR_STATE, 'set particles before bodies')
    end if
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'body needs one entry per particle')
    end if
    if (st%ok() .and. any(body < 1)) call st%set(CPDI_ERR_INPUT, 'body indices start at 1')
    if (st%ok() .and. (contact < 0 .or. contact > 1)) call st%set(CPDI_ERR_INPUT, 'contact is a flag: 0 or 1')
    if (st%ok() .and. .not. (friction >= 0.0_wp .and. friction <= huge(1.0_wp))) &
      call st%set(CPDI_ERR_INPUT, 'friction must be zero or positive and finite')
    if (st%ok()) then
      if (allocated(s%body)) deallocate (s%body)
      allocate (s%body(n))
      s%body = body
      s%contact = contact == 1
      s%friction = friction
      s%fullness = fullness
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_bodies

  subroutine cpdi_set_state(handle, n, v, F, t, ierr, msg)
    !! Overwrite particle velocities, deformation gradients (4,n) and the clock, e.g. to
    !! impose an initial deformation; stress, volume and domains follow from F.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n
    real(c_double), intent(in) :: v(2, n), F(4, n)
    real(c_double), intent(in) :: t
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: ip
    call lookup(handle, s, st)
    if (st%ok()) then
      if (.not. s%has_particles) call st%set(CPDI_ERR_STATE, 'set particles before their state')
    end if
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'state arrays must have one column per particle')
    end if
    if (st%ok()) then
      if (.not. (finite_all(reshape(v, [2*n])) .and. finite_all(reshape(F, [4*n])) .and. abs(t) <= huge(t))) then
        call st%set(CPDI_ERR_INPUT, 'state contains NaN or Inf; give finite values')
      else if (any(F(1, :)*F(4, :) - F(3, :)*F(2, :) <= 0.0_wp)) then
        call st%set(CPDI_ERR_INPUT, 'deformation gradient with det F <= 0; give det F > 0')
      end if
    end if
    if (st%ok()) then
      s%p%v = v
      s%p%F = F
      s%t = t
      do ip = 1, n
        s%p%jbar(ip) = det2(F(:, ip))
        s%p%vol(ip) = s%p%jbar(ip)*s%p%vol0(ip)
      end do
      call map_domains(1, n, s%p%F, s%p%r0, s%p%r)
      s%smax = -1.0_wp
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_state

  subroutine cpdi_set_body_force(handle, n, b, ierr, msg)
    !! External body force per unit mass b(2,n) [m/s^2], added to gravity, kept until reset.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n
    real(c_double), intent(in) :: b(2, n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) then
      if (.not. s%has_particles) call st%set(CPDI_ERR_STATE, 'set particles before body forces')
    end if
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'body force needs one column per particle')
    end if
    if (st%ok() .and. .not. finite_all(reshape(b, [2*n]))) &
      call st%set(CPDI_ERR_INPUT, 'body force contains NaN or Inf')
    if (st%ok()) s%p%bf = b
    call finish(st, ierr, msg)
  end subroutine cpdi_set_body_force

  subroutine cpdi_advance(handle, t_end, max_steps, land, nsteps, t, ierr, msg)
    !! Step until the clock reaches t_end (the last step is shortened to land on it) or
    !! max_steps steps were taken. Returns the steps taken and the new time. With land = 0,
    !! incompressible water does not shorten its steps: the clock passes t_end by less than
    !! one step (its pressure on a sliver step would be the transfer's impulse over a tiny
    !! dt); the weakly compressible model always lands.
    integer(c_int), intent(in) :: handle
    real(c_double), intent(in) :: t_end
    integer(c_int), intent(in) :: max_steps, land
    integer(c_int), intent(out) :: nsteps
    real(c_double), intent(out) :: t
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    real(wp) :: eps
    nsteps = 0
    t = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) call opt_check(s%ov, st)
    if (st%ok()) call sim_prepare(s, st)
    if (st%ok() .and. .not. (abs(t_end) <= huge(t_end))) call st%set(CPDI_ERR_INPUT, 't_end must be finite')
    if (st%ok()) then
      eps = 1.0e-12_wp*max(abs(t_end), 1.0e-300_wp)
      do while (s%t < t_end - eps .and. nsteps < max_steps)
        if (land == 0 .and. s%opt%fluid == FLUID_INCOMPRESSIBLE) then
          call sim_step(s, huge(1.0_wp), st)
        else
          call sim_step(s, t_end - s%t, st)
        end if
        if (.not. st%ok()) exit
        nsteps = nsteps + 1
      end do
      t = s%t
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_advance

  subroutine cpdi_stable_dt(handle, dt, ierr, msg)
    !! Stable time step of the current state (before the CFL factor) [s].
    integer(c_int), intent(in) :: handle
    real(c_double), intent(out) :: dt
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    dt = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) call sim_prepare(s, st)
    if (st%ok()) dt = sim_stable_dt(s)
    call finish(st, ierr, msg)
  end subroutine cpdi_stable_dt

  subroutine cpdi_threads(nreq, nused, ierr, msg)
    !! OpenMP threads of this process's solver: nreq > 0 sets them (omp_set_num_threads),
    !! nreq = 0 only asks. nused is the number the next step will use (1 in a build
    !! without OpenMP).
    !$ use omp_lib, only: omp_set_num_threads, omp_get_max_threads
    integer(c_int), intent(in) :: nreq
    integer(c_int), intent(out) :: nused
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    if (nreq < 0) call st%set(CPDI_ERR_INPUT, 'the thread count must be >= 1 (or 0 to ask)')
    !$ if (st%ok() .and. nreq > 0) call omp_set_num_threads(nreq)
    nused = 1
    !$ nused = omp_get_max_threads()
    call finish(st, ierr, msg)
  end subroutine cpdi_threads

  subroutine cpdi_get_state(handle, n, x, v, F, sig, vol, r, ierr, msg)
    !! Copy out particle positions, velocities, F (4,n), Cauchy stress (4,n)
    !! [sxx, syy, sxy, szz], current volumes and current domain vectors (4,n).
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n
    real(c_double), intent(out) :: x(2, n), v(2, n), F(4, n), sig(4, n), vol(n), r(4, n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    x = 0.0_wp
    v = 0.0_wp
    F = 0.0_wp
    sig = 0.0_wp
    vol = 0.0_wp
    r = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) then
      if (.not. s%has_particles) call st%set(CPDI_ERR_STATE, 'no particles set')
    end if
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'output arrays must have one column per particle')
    end if
    if (st%ok()) then
      x = s%p%x
      v = s%p%v
      F = s%p%F
      sig = s%p%sig
      vol = s%p%vol
      r = s%p%r
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_get_state

  subroutine cpdi_get_diag(handle, diag, ierr, msg)
    !! diag = [t, dt, steps, kinetic, strain energy, momentum x, y, work of gravity,
    !!         work of body forces, total mass, max signal speed, wall clamps last step,
    !!         frictional work of contact, viscous dissipation]
    integer(c_int), intent(in) :: handle
    real(c_double), intent(out) :: diag(NDIAG)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    diag = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) diag = s%diag
    call finish(st, ierr, msg)
  end subroutine cpdi_get_diag

  subroutine cpdi_rigid_bodies(handle, nmax, nb, state, ierr, msg)
    !! The free rigid bodies (rigid_body materials) of an incompressible run, as of its last step:
    !! nb of them (at most nmax listed), state(:, b) = [mass, moment of inertia about the centre,
    !! centre x, y, velocity x, y, angular velocity (after the step), the water's force x, y and
    !! torque about the centre during the step] [kg/m, kg m^2/m, m, m/s, 1/s, N/m, N m/m].
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: nmax
    integer(c_int), intent(out) :: nb
    real(c_double), intent(out) :: state(10, nmax)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: b
    nb = 0
    state = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) then
      nb = s%inc%rb%n
      do b = 1, min(nb, nmax)
        state(:, b) = [s%inc%rb%m(b), s%inc%rb%inertia(b), s%inc%rb%xc(:, b), s%inc%rb%v(:, b), s%inc%rb%w(b), &
                       s%inc%rb%force(:, b)]
      end do
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_rigid_bodies

  subroutine cpdi_solid_force(handle, f, ierr, msg)
    !! Force [N per m of depth] of incompressible water on the solids coupled to it in the last
    !! step: the solid particles' momentum change by the projection over dt (0 otherwise).
    integer(c_int), intent(in) :: handle
    real(c_double), intent(out) :: f(2)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    f = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) f = s%inc%fsolid
    call finish(st, ierr, msg)
  end subroutine cpdi_solid_force

  subroutine cpdi_set_velocity_table(handle, imat, nrow, rows, ierr, msg)
    !! Give rigid material imat (1-based) a velocity table: rows(:, k) = [t, vx, vy] [s, m/s], times
    !! strictly increasing; piecewise linear between rows, held before the first and after the last
    !! (cpdi_motion). It replaces the material's constant velocity until set_materials is called again.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: imat, nrow
    real(c_double), intent(in) :: rows(3, nrow)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    character(len=200) :: buf
    call lookup(handle, s, st)
    if (st%ok()) then
      if (.not. s%has_materials) call st%set(CPDI_ERR_STATE, 'set the materials before a velocity table')
    end if
    if (st%ok()) then
      if (imat < 1 .or. imat > size(s%mats)) then
        write (buf, '(a,i0,a,i0,a)') 'material ', imat, ' does not exist (there are ', size(s%mats), ')'
        call st%set(CPDI_ERR_INPUT, trim(buf))
      else if (s%mats(imat)%model /= MAT_RIGID) then
        write (buf, '(a,i0,a)') 'material ', imat, ' is not rigid: only a rigid (prescribed) body follows '// &
          'a velocity table'
        call st%set(CPDI_ERR_INPUT, trim(buf))
      end if
    end if
    if (st%ok()) then
      if (.not. allocated(s%vtab)) allocate (s%vtab(size(s%mats)))
      call vtable_set(s%vtab(imat), rows, st)
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_velocity_table

  subroutine cpdi_water_loads(handle, n, wl, ierr, msg)
    !! The incompressible water's load on every solid particle in the last coupled step (cpdi_loads):
    !! wl(:, ip) = [fx, fy, c], force [N/m] and couple about the particle's centre [N m/m]. The
    !! moment about a point O of a set of particles is sum (x_p - O) x f_p + c_p. Zeros for water
    !! particles, before the first step, and in runs without solids in incompressible water.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n
    real(c_double), intent(out) :: wl(3, n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    wl = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'n must equal the number of particles')
    end if
    if (st%ok()) then
      if (allocated(s%ld%wl)) then
        if (size(s%ld%wl, 2) == n) wl = s%ld%wl
      end if
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_water_loads

  subroutine cpdi_get_timers(handle, timers, ierr, msg)
    !! Seconds spent per phase: shape, P2G, grid, G2P, deformation, stress, projection.
    integer(c_int), intent(in) :: handle
    real(c_double), intent(out) :: timers(NTIMER)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    timers = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) timers = s%timers
    call finish(st, ierr, msg)
  end subroutine cpdi_get_timers

  subroutine cpdi_set_option(handle, name, n, values, ierr, msg)
    !! Solver option name = values(1:n), by name: every option is a row of the table in
    !! cpdi_options (cpdi_option_info lists them), which checks the value in one place (kind,
    !! components, range). An enum takes its value's 0-based index, a flag 0 or 1. The rules
    !! between options are checked by cpdi_check_options (and before every advance).
    integer(c_int), intent(in) :: handle
    character(len=*), intent(in) :: name
    integer(c_int), intent(in) :: n
    real(c_double), intent(in) :: values(n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) then
      call opt_set(s%ov, name, values, st)
      if (st%ok()) then
        call sim_apply_options(s)
        s%smax = -1.0_wp
      end if
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_option

  subroutine cpdi_slot_count(kind, n)
    !! Named slots of kind 1 diagnostics, 2 timers, 3 fields of the full state's particle rows,
    !! 4 the full state's leading scalars (then come the diagnostics and the timers); 0 otherwise.
    integer(c_int), intent(in) :: kind
    integer(c_int), intent(out) :: n
    select case (kind)
    case (1)
      n = int(NDIAG, c_int)
    case (2)
      n = int(NTIMER, c_int)
    case (3)
      n = int(NROWFIELD, c_int)
    case (4)
      n = int(NSCALAR, c_int)
    case default
      n = 0
    end select
  end subroutine cpdi_slot_count

  subroutine cpdi_slot_info(kind, i, name, width, ierr, msg)
    !! Slot i (1-based) of kind (cpdi_slot_count): its name (cpdi_slots) and width (the rows a
    !! particle field of the full state spans; 1 otherwise).
    integer(c_int), intent(in) :: kind, i
    character(len=SLOT_NAME_LEN), intent(out) :: name
    integer(c_int), intent(out) :: width
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    integer(c_int) :: n
    name = ''
    width = 1
    call cpdi_slot_count(kind, n)
    if (i < 1 .or. i > n) then
      call st%set(CPDI_ERR_INPUT, 'slot out of range; use kind 1-4 and 1 .. cpdi_slot_count(kind)')
    else
      select case (kind)
      case (1)
        name = DIAG_NAMES(i)
      case (2)
        name = TIMER_NAMES(i)
      case (3)
        name = ROW_NAMES(i)
        width = int(merge(NPSTATE + 1, ROW_FIRST(min(i + 1, n)), i == n) - ROW_FIRST(i), c_int)
      case (4)
        name = SCALAR_NAMES(i)
      end select
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_slot_info

  subroutine cpdi_check_options(handle, ierr, msg)
    !! The rules between a simulation's options (a fixed dt is positive; apic needs the
    !! incompressible water): the case loader runs it on a scratch simulation.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) call opt_check(s%ov, st)
    call finish(st, ierr, msg)
  end subroutine cpdi_check_options

  subroutine cpdi_option_count(n)
    !! Rows of the option table.
    integer(c_int), intent(out) :: n
    n = int(NOPT, c_int)
  end subroutine cpdi_option_count

  subroutine cpdi_option_info(i, name, kind, ncomp, default, lo, hi, lo_open, hi_open, in_case, choices, unit, &
                              help, ierr, msg)
    !! Row i (1-based) of the option table (cpdi_options): name; kind 1 real, 2 whole number,
    !! 3 flag, 4 enum; components; default (an enum: its index); range lo..hi (+-huge:
    !! unbounded) with open ends flagged 1; in_case 0 not a case key, 1 a [solver] key with the
    !! default, 2 a [solver] key without one; an enum's '|'-separated value names; unit; help.
    integer(c_int), intent(in) :: i
    character(len=OPT_NAME_LEN), intent(out) :: name
    integer(c_int), intent(out) :: kind, ncomp, lo_open, hi_open, in_case
    real(c_double), intent(out) :: default, lo, hi
    character(len=OPT_CHOICE_LEN), intent(out) :: choices
    character(len=OPT_UNIT_LEN), intent(out) :: unit
    character(len=OPT_HELP_LEN), intent(out) :: help
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    name = ''
    kind = 0
    ncomp = 0
    lo_open = 0
    hi_open = 0
    in_case = 0
    default = 0.0_wp
    lo = 0.0_wp
    hi = 0.0_wp
    choices = ''
    unit = ''
    help = ''
    if (i < 1 .or. i > NOPT) then
      call st%set(CPDI_ERR_INPUT, 'option row out of range; use 1 .. cpdi_option_count')
    else
      name = OPTIONS(i)%name
      kind = int(OPTIONS(i)%kind, c_int)
      ncomp = int(OPTIONS(i)%ncomp, c_int)
      default = OPTIONS(i)%default
      lo = OPTIONS(i)%lo
      hi = OPTIONS(i)%hi
      lo_open = merge(1_c_int, 0_c_int, OPTIONS(i)%lo_open)
      hi_open = merge(1_c_int, 0_c_int, OPTIONS(i)%hi_open)
      in_case = int(OPTIONS(i)%in_case, c_int)
      choices = OPTIONS(i)%choices
      unit = OPTIONS(i)%unit
      help = OPTIONS(i)%help
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_option_info

  subroutine cpdi_face_velocity(handle, nx, ny, u, v, ierr, msg)
    !! Face velocities after the last step of an incompressible run, (nx, ny) = cells:
    !! u(i, j) on the left face of cell (i, j) (i = nx + 1: the right wall), v(i, j) on its
    !! bottom face (j = ny + 1: the top).
    integer(c_int), intent(in) :: handle, nx, ny
    real(c_double), intent(out) :: u(nx + 1, ny), v(nx, ny + 1)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: j, k0
    u = 0.0_wp
    v = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) then
      if (.not. allocated(s%inc%mc%cell)) &
        call st%set(CPDI_ERR_STATE, 'no face velocities: they exist once an incompressible run has been prepared')
    end if
    if (st%ok()) then
      if (nx /= s%g%ncell(1) .or. ny /= s%g%ncell(2)) &
        call st%set(CPDI_ERR_INPUT, 'nx, ny must be the grid''s cell counts')
    end if
    if (st%ok()) then
      do j = 1, ny + 1
        k0 = s%inc%mc%lo(1) + (s%inc%mc%lo(2) + j - 2)*s%inc%mc%nn(1)
        if (j <= ny) u(:, j) = s%inc%mc%u(k0:k0 + nx)
        v(:, j) = s%inc%mc%v(k0:k0 + nx - 1)
      end do
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_face_velocity

  subroutine cpdi_grid_pressure(handle, nx, ny, p, fill, cell, ierr, msg)
    !! Pressure [Pa] (0 outside the water), fill fraction and kind (0 air, 1 water) of the
    !! physical cells after the last step of an incompressible run, (nx, ny) = cells.
    integer(c_int), intent(in) :: handle, nx, ny
    real(c_double), intent(out) :: p(nx, ny), fill(nx, ny)
    integer(c_int), intent(out) :: cell(nx, ny)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: j, k0
    p = 0.0_wp
    fill = 0.0_wp
    cell = 0
    call lookup(handle, s, st)
    ! the grid exists from the start (a snapshot at t = 0); once it does, preparing again
    ! would clear its water marks, so only a run that has not been prepared is
    if (st%ok()) then
      if (.not. allocated(s%inc%mc%cell)) call sim_prepare(s, st)
    end if
    if (st%ok()) then
      if (.not. allocated(s%inc%mc%cell)) &
        call st%set(CPDI_ERR_STATE, 'no pressure grid: only incompressible runs (solver.fluid = "incompressible") have one')
    end if
    if (st%ok()) then
      if (nx /= s%g%ncell(1) .or. ny /= s%g%ncell(2)) &
        call st%set(CPDI_ERR_INPUT, 'nx, ny must be the grid''s cell counts')
    end if
    if (st%ok()) then
      do j = 1, ny
        k0 = s%inc%mc%lo(1) + (s%inc%mc%lo(2) + j - 2)*s%inc%mc%nn(1)
        p(:, j) = s%inc%mc%p(k0:k0 + nx - 1)
        fill(:, j) = s%inc%mc%fill(k0:k0 + nx - 1)
        cell(:, j) = merge(1, 0, s%inc%mc%cell(k0:k0 + nx - 1) == CELL_FLUID)
      end do
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_grid_pressure

  subroutine cpdi_transfer_cycle(handle, ierr, msg)
    !! Incompressible runs: particle-to-grid transfer to the face lattices and back, nothing
    !! else (PIC, or APIC with transfer = apic). A test of what the transfer conserves.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) then
      if (s%opt%fluid /= FLUID_INCOMPRESSIBLE) &
        call st%set(CPDI_ERR_STATE, 'the face-lattice transfer belongs to fluid = incompressible; set it first')
    end if
    if (st%ok()) call sim_prepare(s, st)
    if (st%ok()) call incomp_transfer_cycle(s%inc, s%g, s%p, st)
    call finish(st, ierr, msg)
  end subroutine cpdi_transfer_cycle

  subroutine cpdi_pressure_stats(handle, stats, ierr, msg)
    !! The last pressure solve of an incompressible run: [CG iterations, relative residual,
    !! closed-water defect of the right-hand side, closed water regions, preconditioner (0 mic0,
    !! 1 multigrid)] (cpdi_pressure).
    integer(c_int), intent(in) :: handle
    real(c_double), intent(out) :: stats(5)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    stats = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) stats = [real(s%inc%mc%iters, wp), s%inc%mc%resid, s%inc%mc%defect, real(s%inc%mc%nfloat, wp), &
                          real(s%inc%mc%precond, wp)]
    call finish(st, ierr, msg)
  end subroutine cpdi_pressure_stats

  subroutine cpdi_grid_info(handle, info, ierr, msg)
    !! info = [x of node (1,1), y of node (1,1), h, nodes in x, nodes in y, pad]
    integer(c_int), intent(in) :: handle
    real(c_double), intent(out) :: info(6)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    info = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) then
      if (.not. s%has_grid) call st%set(CPDI_ERR_STATE, 'no grid set')
    end if
    if (st%ok()) info = [s%g%gorig(1), s%g%gorig(2), s%g%h, real(s%g%nn(1), wp), real(s%g%nn(2), wp), &
                         real(GRID_PAD, wp)]
    call finish(st, ierr, msg)
  end subroutine cpdi_grid_info

  subroutine cpdi_get_shape(handle, n, ns, idx, w, gx, gy, ierr, msg)
    !! Interpolation weights of the current configuration: for each particle ns slots of
    !! 1-based node index, S_ip and grad S_ip. Unused slots have weight 0.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n, ns
    integer(c_int), intent(out) :: idx(ns, n)
    real(c_double), intent(out) :: w(ns, n), gx(ns, n), gy(ns, n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: a, ip
    idx = 1
    w = 0.0_wp
    gx = 0.0_wp
    gy = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) call sim_prepare(s, st)
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'output arrays must have one column per particle')
    end if
    if (st%ok()) call sim_check_inside(s, st)
    if (st%ok()) then
      if (ns < s%sh%ns) call st%set(CPDI_ERR_INPUT, 'ns is smaller than the slots of this shape')
    end if
    if (st%ok()) then
      do ip = 1, n
        do a = 1, shape_count(s%sh, ip)
          call shape_slot(s%sh, ip, a, idx(a, ip), w(a, ip), gx(a, ip), gy(a, ip))
        end do
      end do
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_get_shape

  subroutine cpdi_project(handle, n, mode, mask, val, ierr, msg)
    !! Project a particle field val(n) with the current configuration and the run's
    !! interpolation: mode 1 cell-wise constant, 2 nodal bilinear. Only particles with
    !! mask /= 0 take part; the others keep their values.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: n, mode
    integer(c_int), intent(in) :: mask(n)
    real(c_double), intent(inout) :: val(n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    call lookup(handle, s, st)
    if (st%ok()) call sim_prepare(s, st)
    if (st%ok()) then
      if (n /= s%p%n) call st%set(CPDI_ERR_INPUT, 'val must have one entry per particle')
    end if
    if (st%ok() .and. (mode < 1 .or. mode > 2)) call st%set(CPDI_ERR_INPUT, 'mode must be 1 (cell) or 2 (nodal)')
    if (st%ok() .and. .not. finite_all(val)) call st%set(CPDI_ERR_INPUT, 'val contains NaN or Inf')
    if (st%ok()) call sim_check_inside(s, st)
    if (st%ok()) then
      if (.not. allocated(s%proj%qc)) then
        call projection_alloc(s%proj, s%g, s%p%n, st)
      else if (size(s%proj%qc, 2) /= s%p%n .or. size(s%proj%hd) /= s%g%nnodes) then
        call projection_alloc(s%proj, s%g, s%p%n, st)
      end if
      if (st%ok()) call project_scalar(s%proj, mode, s%opt%shape, s%g, s%p, mask /= 0, val, st)
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_project

  subroutine cpdi_log_strain(n, F, method, eps, ierr, msg)
    !! Log strain 1/2 log(F F^T) of n plane-strain gradients F(4,n); eps(3,n) = [e11, e22, e12].
    !! method 0: closed form used by the solver; 1: LAPACK dsyev.
    integer(c_int), intent(in) :: n
    real(c_double), intent(in) :: F(4, n)
    integer(c_int), intent(in) :: method
    real(c_double), intent(out) :: eps(3, n)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    integer(ik) :: ip, info
    character(len=120) :: buf
    eps = 0.0_wp
    if (method /= 0 .and. method /= 1) call st%set(CPDI_ERR_INPUT, 'method must be 0 (closed form) or 1 (dsyev)')
    do ip = 1, n
      if (.not. st%ok()) exit
      if (.not. (det2(F(:, ip)) > 0.0_wp) .or. .not. finite_all(F(:, ip))) then
        write (buf, '(a,i0,a)') 'F number ', ip, ' has det F <= 0 or is not finite; log strain needs J > 0'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        exit
      end if
      if (method == 0) then
        call log_strain(F(:, ip), eps(:, ip))
      else
        call log_strain_lapack(F(:, ip), eps(:, ip), info)
        if (info /= 0) call st%set(CPDI_ERR_LAPACK, 'dsyev failed')
      end if
    end do
    call finish(st, ierr, msg)
  end subroutine cpdi_log_strain

  subroutine cpdi_full_state_size(nprow, nscal, ierr, msg)
    !! Sizes of the full-state arrays of cpdi_get_full_state and cpdi_set_full_state.
    integer(c_int), intent(out) :: nprow   !! rows per particle
    integer(c_int), intent(out) :: nscal   !! scalars
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    nprow = NPSTATE
    nscal = NSSTATE
    call finish(st, ierr, msg)
  end subroutine cpdi_full_state_size

  subroutine check_full_state_dims(s, nprow, n, nscal, st)
    !! Refuse full-state arrays that do not fit this solver and this simulation.
    type(sim_t), intent(in) :: s
    integer(c_int), intent(in) :: nprow, n, nscal
    type(status_t), intent(inout) :: st
    character(len=240) :: buf
    if (.not. s%has_particles) then
      call st%set(CPDI_ERR_STATE, 'no particles set; build the simulation (grid, materials, particles, bodies, '// &
                  'options) before its full state')
    else if (nprow /= NPSTATE .or. nscal /= NSSTATE) then
      write (buf, '(a,i0,a,i0,a,i0,a,i0,a)') 'full state has ', nprow, ' rows per particle and ', nscal, &
        ' scalars but this solver uses ', NPSTATE, ' and ', NSSTATE, &
        '; it comes from another solver version, rerun from t = 0'
      call st%set(CPDI_ERR_INPUT, trim(buf))
    else if (n /= s%p%n) then
      write (buf, '(a,i0,a,i0,a)') 'full state holds ', n, ' particles but the simulation has ', s%p%n, &
        '; restore it into a simulation built from the same case'
      call st%set(CPDI_ERR_INPUT, trim(buf))
    end if
  end subroutine check_full_state_dims

  subroutine cpdi_get_full_state(handle, nprow, n, nscal, pstate, sstate, ierr, msg)
    !! Copy out everything stepping depends on, so that a simulation rebuilt from the same
    !! case and given this state by cpdi_set_full_state continues bit for bit.
    !! pstate(:, ip) = [x(2), v(2), F(4), L(4), sig(4), r(4), bf(2), vol, psi, jbar, aw(2)];
    !! sstate = [t, steps, smax, visc_dt, dt_last, diag(NDIAG), timers(NTIMER)].
    !! Mass, vol0, r0, material and body come from the case and are not included; grid,
    !! shape and projection arrays are rebuilt at every step and carry no state.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: nprow, n, nscal
    real(c_double), intent(out) :: pstate(nprow, n)
    real(c_double), intent(out) :: sstate(nscal)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    pstate = 0.0_wp
    sstate = 0.0_wp
    call lookup(handle, s, st)
    if (st%ok()) call check_full_state_dims(s, nprow, n, nscal, st)
    if (st%ok()) then
      pstate(ROW_X:ROW_X + 1, :) = s%p%x
      pstate(ROW_V:ROW_V + 1, :) = s%p%v
      pstate(ROW_F:ROW_F + 3, :) = s%p%F
      pstate(ROW_L:ROW_L + 3, :) = s%p%L
      pstate(ROW_SIG:ROW_SIG + 3, :) = s%p%sig
      pstate(ROW_R:ROW_R + 3, :) = s%p%r
      pstate(ROW_BF:ROW_BF + 1, :) = s%p%bf
      pstate(ROW_VOL, :) = s%p%vol
      pstate(ROW_PSI, :) = s%p%psi
      pstate(ROW_JBAR, :) = s%p%jbar
      pstate(ROW_AW:ROW_AW + 1, :) = s%p%aw
      sstate(SCAL_T) = s%t
      sstate(SCAL_STEPS) = real(s%steps, wp)
      sstate(SCAL_SMAX) = s%smax
      sstate(SCAL_VISC_DT) = s%visc_dt
      sstate(SCAL_DT_LAST) = s%dt_last
      sstate(NSCALAR + 1:NSCALAR + NDIAG) = s%diag
      sstate(NSCALAR + NDIAG + 1:NSSTATE) = s%timers
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_get_full_state

  subroutine cpdi_set_full_state(handle, nprow, n, nscal, pstate, sstate, ierr, msg)
    !! Restore a state written by cpdi_get_full_state (layout there). Call it after the
    !! set_* routines, which mark the stress as stale: this restores the stress and the
    !! signal speed as they were, so the next step does not recompute (and re-accumulate)
    !! anything and continues bit for bit.
    integer(c_int), intent(in) :: handle
    integer(c_int), intent(in) :: nprow, n, nscal
    real(c_double), intent(in) :: pstate(nprow, n)
    real(c_double), intent(in) :: sstate(nscal)
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    type(sim_t), pointer :: s
    integer(ik) :: ip
    character(len=200) :: buf
    call lookup(handle, s, st)
    if (st%ok()) call check_full_state_dims(s, nprow, n, nscal, st)
    if (st%ok()) then
      if (.not. (finite_all(reshape(pstate, [nprow*n])) .and. finite_all(sstate))) then
        call st%set(CPDI_ERR_INPUT, 'full state contains NaN or Inf; it is damaged, use another checkpoint '// &
                    'or rerun from t = 0')
      else if (.not. (sstate(SCAL_T) >= 0.0_wp .and. sstate(SCAL_STEPS) >= 0.0_wp &
                      .and. sstate(SCAL_STEPS) == aint(sstate(SCAL_STEPS)) .and. sstate(SCAL_STEPS) < 2.0_wp**53 &
                      .and. sstate(SCAL_VISC_DT) > 0.0_wp .and. sstate(SCAL_DT_LAST) >= 0.0_wp)) then
        call st%set(CPDI_ERR_INPUT, 'full state has a negative time or time step, a step count that is not '// &
                    'a whole number, or a viscous limit <= 0; it is damaged, use another checkpoint')
      end if
    end if
    if (st%ok()) then
      do ip = 1, n
        if (.not. (det2(pstate(ROW_F:ROW_F + 3, ip)) > 0.0_wp .and. det2(pstate(ROW_R:ROW_R + 3, ip)) > 0.0_wp &
                   .and. &
                   pstate(ROW_VOL, ip) > 0.0_wp .and. pstate(ROW_JBAR, ip) > 0.0_wp)) then
          write (buf, '(a,i0,a)') 'full state of particle ', ip, ' has det F, domain area, volume or J <= 0; '// &
            'it is damaged, use another checkpoint or rerun from t = 0'
          call st%set(CPDI_ERR_INPUT, trim(buf))
          exit
        end if
      end do
    end if
    if (st%ok()) then
      s%p%x = pstate(ROW_X:ROW_X + 1, :)
      s%p%v = pstate(ROW_V:ROW_V + 1, :)
      s%p%F = pstate(ROW_F:ROW_F + 3, :)
      s%p%L = pstate(ROW_L:ROW_L + 3, :)
      s%p%sig = pstate(ROW_SIG:ROW_SIG + 3, :)
      s%p%r = pstate(ROW_R:ROW_R + 3, :)
      s%p%bf = pstate(ROW_BF:ROW_BF + 1, :)
      s%p%vol = pstate(ROW_VOL, :)
      s%p%psi = pstate(ROW_PSI, :)
      s%p%jbar = pstate(ROW_JBAR, :)
      s%p%aw = pstate(ROW_AW:ROW_AW + 1, :)
      s%t = sstate(SCAL_T)
      s%steps = int(sstate(SCAL_STEPS), kind(s%steps))
      s%smax = sstate(SCAL_SMAX)
      s%visc_dt = sstate(SCAL_VISC_DT)
      s%dt_last = sstate(SCAL_DT_LAST)
      s%diag = sstate(NSCALAR + 1:NSCALAR + NDIAG)
      s%timers = sstate(NSCALAR + NDIAG + 1:NSSTATE)
    end if
    call finish(st, ierr, msg)
  end subroutine cpdi_set_full_state
  elemental logical function area_ok(r1x, r1y, r2x, r2y)
    !! A particle domain r1 x r2 has positive area, beyond round-off: the cross product
    !! r1x r2y - r1y r2x above 1e-12 |r1| |r2| (a zero-area domain can come out as a tiny
    !! positive number when the compiler fuses the products).
    real(c_double), intent(in) :: r1x, r1y, r2x, r2y
    area_ok = r1x*r2y - r1y*r2x > 1.0e-12_wp*hypot(r1x, r1y)*hypot(r2x, r2y)
  end function area_ok

  pure function domain_ok(r) result(ok)
    !! area_ok of every particle's domain vectors r(1:4, ip) = [r1x, r1y, r2x, r2y].
    real(c_double), intent(in) :: r(:, :)
    logical :: ok(size(r, 2))
    ok = area_ok(r(1, :), r(2, :), r(3, :), r(4, :))
  end function domain_ok

end module cpdi_api
