!> The simulation object and the explicit MPM step.
module cpdi_step
  !! One step: time step from the signal speed, interpolation weights, particle-to-grid
  !! transfer, grid momentum update with walls and rigid nodes, grid-to-particle
  !! transfer (USL or MUSL), deformation update (F, volume, CPDI domains), stress.
  !! Fluid particles keep an isotropic F = sqrt(J) I: a Newtonian fluid's stress depends
  !! on J and the rate D only, and an accumulated total shear would distort (and
  !! eventually invert) their CPDI domains without physical meaning.
  !! Diagnostics are accumulated inside the same loops; nothing is allocated per step.
  !!
  !! OpenMP: one parallel region per step (sim_step); the phases are orphaned worksharing
  !! constructs, so they also run serially when called outside a region (sim_prepare).
  !! Every particle loop runs over the fixed blocks of cpdi_schedule (gathers, reductions
  !! summed block by block in a fixed order, max/min per block) and every scatter to the
  !! grid over its two-colour strips, so a run gives the same bits at any thread count.
  !! Node loops are static worksharing loops. Contact, walls, reductions and error scans
  !! run in `single` (they touch few nodes). Locals of a phase routine are private to each
  !! thread; anything shared lives in sim_t.
  use, intrinsic :: iso_fortran_env, only: int64
  !$ use omp_lib, only: omp_get_max_threads
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT, CPDI_ERR_STATE, CPDI_ERR_NAN, &
                         CPDI_ERR_OUTSIDE, CPDI_ERR_JACOBIAN, CPDI_ERR_DOMAIN, CPDI_ERR_CFL
  use cpdi_grid, only: grid_t, grid_apply_walls, grid_fields, hold_on_walls, WALL_OPEN
  use cpdi_contact, only: contact_correct
  use cpdi_particles, only: particles_t
  use cpdi_shape, only: shape_t, shape_alloc, shape_compute, shape_count, shape_slot, SHAPE_GIMP, &
                        SHAPE_CPDI, SHAPE_FAIL_INVERTED
  use cpdi_schedule, only: strips_t, strips_alloc, strips_build, NCHUNK, chunk_range
  use cpdi_materials, only: material_t, material_stresses, MAT_FLUID, KIN_LOG
  use cpdi_kinematics, only: det2, map_domains
  use cpdi_projection, only: projection_t, projection_alloc, projection_setup, projection_apply, PROJ_NONE
  use cpdi_incompressible, only: incomp_t, incomp_prepare, incomp_step, FLUID_INCOMPRESSIBLE, &
                                 FLUID_WEAKLY_COMPRESSIBLE
  implicit none
  private

  integer(ik), parameter, public :: UPDATE_USL = 0
  integer(ik), parameter, public :: UPDATE_MUSL = 1

  integer(ik), parameter, public :: NDIAG = 18
  !! diag: 1 t, 2 dt, 3 steps, 4 kinetic energy, 5 strain energy, 6-7 momentum,
  !! 8 work of gravity, 9 work of body forces, 10 total mass, 11 max signal speed,
  !! 12 particles clamped at walls during the last step, 13 frictional work of contact,
  !! 14 viscous dissipation; incompressible water: 15 CG iterations and 16 relative
  !! residual of the last pressure solve, 17 CG iterations of all steps, 18 work of gravity
  !! on the volume correction's displacements (not in 8: the correction is no flow)
  integer(ik), parameter :: MIN_PER_THREAD = 16384
  !! particles per thread below which a step uses fewer threads: a step has about 20
  !! barriers, and on the 2-core VM 8k CPDI particles ran 1.4x slower on 2 threads than on 1
  !! (passive waits, docs/notes/threads.md) while 32k ran faster. Results do not depend on it.
  !! The environment variable CPDI_MIN_PER_THREAD (read by sim_prepare) replaces it; the
  !! tests set it to 1 so that their small cases really run on several threads.
  integer(ik), parameter, public :: NTIMER = 8
  !! timers [s]: 1 shape functions (and strips), 2 P2G, 3 grid, 4 G2P (and MUSL remap),
  !! 5 F and domains, 6 stress, 7 projection (operator, strain increment, mean stress),
  !! 8 pressure solve (incompressible water)

  type, public :: options_t
    integer(ik) :: shape = SHAPE_CPDI        !! SHAPE_MPM, SHAPE_GIMP or SHAPE_CPDI
    integer(ik) :: update = UPDATE_MUSL      !! UPDATE_USL or UPDATE_MUSL
    integer(ik) :: projection = PROJ_NONE    !! PROJ_NONE, PROJ_CELL or PROJ_NODAL
    integer(ik) :: kinematics = KIN_LOG      !! KIN_LOG or KIN_SMALL
    integer(ik) :: domain_scaling = 0        !! 1: Homel et al. (2016) domain scaling
    integer(ik) :: fixed_dt = 0              !! 1: use dt below instead of the CFL step
    integer(ik) :: fluid = FLUID_WEAKLY_COMPRESSIBLE !! water model: explicit weakly compressible or incompressible
    real(wp) :: cfl = 0.3_wp                 !! Courant number
    real(wp) :: gravity(2) = 0.0_wp          !! [m/s^2]
    real(wp) :: damping = 0.0_wp             !! Cundall local damping coefficient [-]
    real(wp) :: dt = 0.0_wp                  !! fixed time step [s]
    real(wp) :: flip = 1.0_wp                !! FLIP fraction of the particle velocity update
    real(wp) :: lcrit = 0.49999_wp           !! domain-scaling limit as a fraction of h
    real(wp) :: pstab = 0.0_wp               !! projection stabilisation beta: keep beta of the raw field
  end type options_t

  type, public :: sim_t
    logical :: has_grid = .false.
    logical :: has_materials = .false.
    logical :: has_particles = .false.
    type(grid_t) :: g
    type(particles_t) :: p
    type(material_t), allocatable :: mats(:)
    logical, allocatable :: rigid(:)         !! per material
    logical, allocatable :: fluid(:)         !! per material: F kept isotropic, sqrt(J) I
    logical :: any_rigid = .false.
    integer(ik), allocatable :: body(:)      !! per particle: body index (1-based)
    integer(ik), allocatable :: field(:)     !! per particle: velocity field (1, or its body with contact)
    logical, allocatable :: field_rigid(:)   !! per field: a rigid body (infinite mass in contact)
    logical, allocatable :: field_solid(:)   !! per field: no fluid particle (walls obey the volume constraint)
    logical :: contact = .false.             !! multi-velocity-field contact between bodies
    real(wp) :: friction = 0.0_wp            !! Coulomb coefficient of contact
    real(wp) :: fullness = 0.9_wp            !! contact needs sum_b V_i^b >= fullness h^2 at the node
    real(wp) :: dt_last = 0.0_wp
    type(shape_t) :: sh
    type(projection_t) :: proj
    type(incomp_t) :: inc                    !! incompressible water: settings and staggered grid
    logical, allocatable :: pmask(:)         !! per particle: takes part in the projection
    type(options_t) :: opt
    real(wp) :: t = 0.0_wp
    integer(int64) :: steps = 0
    real(wp) :: mtol = 0.0_wp                !! nodes lighter than this carry no velocity
    real(wp) :: smax = -1.0_wp               !! max signal speed of the current state (<0: unknown)
    real(wp) :: visc_dt = huge(1.0_wp)       !! viscous time-step limit
    real(wp) :: diag(NDIAG) = 0.0_wp
    real(wp) :: timers(NTIMER) = 0.0_wp
    type(strips_t) :: sp                     !! scatter colouring of the particles (per step)
    integer(ik) :: kprev(2) = [1, huge(1)]   !! nodes the last step's stencils spanned (first, last)
    integer(ik) :: kw(2) = [1, huge(1)]      !! nodes this step clears and updates (first, last)
    real(wp) :: red(6, NCHUNK) = 0.0_wp      !! per-block partial sums of the reductions
    integer(ik) :: cbad(NCHUNK) = 0          !! per-block first failing particle
    real(wp) :: cval(NCHUNK) = 0.0_wp        !! per-block value that made it fail
    real(wp) :: cext(2, NCHUNK) = 0.0_wp     !! per-block max signal speed, min viscous step
    integer(ik) :: min_per_thread = MIN_PER_THREAD   !! CPDI_MIN_PER_THREAD in the environment overrides
  end type sim_t

  public :: sim_prepare, sim_step, sim_stable_dt

contains

  subroutine sim_prepare(s, st)
    !! Check the pieces fit together and bring derived state up to date. Called before
    !! stepping whenever grid, materials, particles or options changed.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: ip
    character(len=200) :: buf
    real(wp) :: lp(2)
    logical :: realloc

    if (.not. (s%has_grid .and. s%has_materials .and. s%has_particles)) then
      call st%set(CPDI_ERR_STATE, 'set the grid, the materials and the particles before stepping')
      return
    end if
    if (any(s%p%mat < 1) .or. any(s%p%mat > size(s%mats))) then
      ip = findloc((s%p%mat < 1) .or. (s%p%mat > size(s%mats)), .true., 1)
      write (buf, '(a,i0,a,i0,a,i0,a)') 'particle ', ip, ' has material ', s%p%mat(ip), &
        ' but only ', size(s%mats), ' materials are defined'
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    if (s%opt%shape == SHAPE_GIMP) then
      do ip = 1, s%p%n
        lp = [abs(s%p%r0(1, ip)) + abs(s%p%r0(3, ip)), abs(s%p%r0(2, ip)) + abs(s%p%r0(4, ip))]
        if (any(lp > 0.5_wp*s%g%h*(1.0_wp + 1.0e-12_wp)) .or. any(.not. (lp > 0.0_wp))) then
          write (buf, '(a,i0,a,2es11.3,a,es11.3,a)') 'particle ', ip, ' has GIMP half-widths ', lp, &
            ' but uGIMP needs 0 < half-width <= h/2 = ', 0.5_wp*s%g%h, '; use 1 or more particles per cell'
          call st%set(CPDI_ERR_INPUT, trim(buf))
          return
        end if
      end do
    end if
    call prepare_fields(s, st)
    if (.not. st%ok()) return
    if (s%opt%fluid == FLUID_INCOMPRESSIBLE) then
      call prepare_incompressible(s, st)
      return
    end if
    ! (Fortran does not short-circuit .or.: test allocation before asking for a size)
    realloc = .not. allocated(s%sh%idx)
    if (.not. realloc) realloc = s%sh%kind /= s%opt%shape .or. size(s%sh%w, 2) /= s%p%n
    if (realloc) then
      call shape_alloc(s%sh, s%opt%shape, s%p%n, st)
      if (.not. st%ok()) return
    end if
    realloc = .not. allocated(s%sp%perm)
    if (.not. realloc) realloc = size(s%sp%perm) /= s%p%n .or. size(s%sp%start) /= s%g%nn(2) + 2
    if (realloc) then
      call strips_alloc(s%sp, s%p%n, s%g%nn(2), st)
      if (.not. st%ok()) return
    end if
    if (s%opt%projection /= PROJ_NONE) then
      realloc = .not. allocated(s%proj%hd)
      if (.not. realloc) realloc = size(s%proj%hd) /= s%g%nnodes .or. size(s%proj%qc, 2) /= s%p%n
      if (realloc) call projection_alloc(s%proj, s%g, s%p%n, st)
      if (.not. st%ok()) return
      if (allocated(s%pmask)) deallocate (s%pmask)
      allocate (s%pmask(s%p%n))
      s%pmask = s%mats(s%p%mat)%project
    end if
    call get_environment_variable('CPDI_MIN_PER_THREAD', buf, status=ip)
    if (ip == 0) then
      read (buf, *, iostat=ip) s%min_per_thread
      if (ip /= 0 .or. s%min_per_thread < 1) s%min_per_thread = MIN_PER_THREAD
    end if
    s%mtol = 1.0e-12_wp*minval(s%p%m)
    s%diag(10) = sum(s%p%m)
    s%kprev = [1_ik, s%g%nnodes]   ! the whole grid may hold values: the next step clears it all
    if (s%smax < 0.0_wp) then   ! stress and signal speed of the current state
      if (s%opt%projection /= PROJ_NONE) &
        call projection_setup(s%proj, s%opt%projection, s%opt%shape, s%g, s%p, s%pmask, st)
      if (st%ok()) call stress_update(s, st)
      if (st%ok() .and. s%opt%projection /= PROJ_NONE) call project_mean_stress(s, st)
    end if
  end subroutine sim_prepare

  subroutine prepare_incompressible(s, st)
    !! The incompressible water model's checks and storage; signal speed of the state.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    if (s%contact) then
      call st%set(CPDI_ERR_INPUT, 'contact is not available with fluid = "incompressible"; '// &
                  'set [contact] enabled = false or use fluid = "weakly_compressible"')
      return
    end if
    if (s%opt%projection /= PROJ_NONE) then
      call st%set(CPDI_ERR_INPUT, 'the volumetric projection is for the weakly compressible model: '// &
                  'incompressible water needs none; set [solver] projection = "none"')
      return
    end if
    call incomp_prepare(s%inc, s%g, s%p, s%mats, s%opt%shape, s%opt%damping, st)
    if (.not. st%ok()) return
    s%diag(10) = sum(s%p%m)
    if (s%smax < 0.0_wp) s%smax = sqrt(2.0_wp)*maxval(abs(s%p%v)) + sqrt(norm2(s%opt%gravity)*s%g%h)
    s%visc_dt = huge(1.0_wp)
    if (s%inc%visc > 0.0_wp) s%visc_dt = 0.25_wp*s%inc%rho*s%g%h**2/s%inc%visc
  end subroutine prepare_incompressible

  subroutine prepare_fields(s, st)
    !! One velocity field, or one per contact group when contact is on. A field made only
    !! of rigid particles acts as an infinite mass in contact; rigid particles inside a
    !! deformable field clamp that field's nodes (e.g. an anchored obstacle).
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: nf, b
    if (.not. allocated(s%body)) then
      allocate (s%body(s%p%n))
      s%body = 1
    end if
    if (size(s%body) /= s%p%n) then
      call st%set(CPDI_ERR_STATE, 'the body indices do not match the particles; set bodies after particles')
      return
    end if
    nf = 1
    if (s%contact) nf = maxval(s%body)
    if (allocated(s%field)) deallocate (s%field, s%field_rigid, s%field_solid)
    allocate (s%field(s%p%n), s%field_rigid(nf), s%field_solid(nf))
    s%field = 1
    if (s%contact) s%field = s%body
    s%field_rigid = .false.
    s%field_solid = .false.
    if (s%contact) then
      do b = 1, nf
        s%field_rigid(b) = all(pack(s%rigid(s%p%mat), s%body == b)) .and. any(s%body == b)
        s%field_solid(b) = .not. any(pack(s%fluid(s%p%mat), s%body == b))
      end do
    end if
    call grid_fields(s%g, nf, s%any_rigid, st)
  end subroutine prepare_fields

  pure real(wp) function sim_stable_dt(s)
    !! Largest stable explicit step, h / max(c + |v|), and the viscous limit.
    type(sim_t), intent(in) :: s
    sim_stable_dt = min(s%g%h/max(s%smax, tiny(1.0_wp)), s%visc_dt)
  end function sim_stable_dt

  subroutine tic(t0)
    integer(int64), intent(out) :: t0
    call system_clock(t0)
  end subroutine tic

  subroutine toc(s, slot, t0)
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: slot
    integer(int64), intent(inout) :: t0
    integer(int64) :: t1, rate
    call system_clock(t1, rate)
    s%timers(slot) = s%timers(slot) + real(t1 - t0, wp)/real(rate, wp)
    t0 = t1
  end subroutine toc

  logical function all_ok(st)
    !! st%ok() as one thread sees it, given to every thread of the region (copyprivate): a
    !! status set in a `single` by another thread is otherwise not guaranteed to be re-read
    !! (the compiler may keep a dummy argument's earlier value across the barrier), and
    !! threads that disagree leave the step at different barriers and hang.
    type(status_t), intent(in) :: st
    logical :: ok
    !$omp single
    ok = st%ok()
    !$omp end single copyprivate(ok)
    all_ok = ok
  end function all_ok

  integer(ik) function all_int(i)
    !! i as one thread sees it, given to every thread of the region (see all_ok).
    integer(ik), intent(in) :: i
    integer(ik) :: v
    !$omp single
    v = i
    !$omp end single copyprivate(v)
    all_int = v
  end function all_int

  subroutine tic_master(t0)
    !! tic on the master thread only (inside or outside a parallel region; no barrier).
    integer(int64), intent(inout) :: t0
    !$omp master
    call tic(t0)
    !$omp end master
  end subroutine tic_master

  subroutine toc_master(s, slot, t0)
    !! toc on the master thread only: the phases end in barriers, so its clock spans a phase.
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: slot
    integer(int64), intent(inout) :: t0
    !$omp master
    call toc(s, slot, t0)
    !$omp end master
  end subroutine toc_master

  subroutine sim_step(s, dt_cap, st)
    !! Advance by one explicit step of at most dt_cap.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt_cap
    type(status_t), intent(inout) :: st
    real(wp) :: dt, dtc
    integer(ik) :: bad, fail
    integer :: nthr
    integer(int64) :: t0
    character(len=300) :: buf
    logical :: proj


    dtc = sim_stable_dt(s)
    if (s%opt%fixed_dt == 1) then
      dt = s%opt%dt
      if (dt > dtc) then
        write (buf, '(a,i0,a,es11.4,a,es11.4,a)') 'step ', s%steps + 1, ': fixed dt = ', dt, &
          ' s exceeds the stable limit h/max(c+|v|) = ', dtc, ' s; reduce [solver] dt or use cfl'
        call st%set(CPDI_ERR_CFL, trim(buf))
        return
      end if
    else
      dt = s%opt%cfl*dtc
    end if
    ! Incompressible water lands on dt_cap in equal steps rather than with a sliver of a
    ! step: its pressure also removes the divergence the transfer leaves (a fixed impulse
    ! per step), so a step of dt -> 0 would show a pressure ~ 1/dt (measured: wall pressure
    ! spikes of 1e3 rho g H at the steps that land on output times). The runner asks it not
    ! to land at all except at t_end (cpdi_advance, land = 0).
    if (s%opt%fluid == FLUID_INCOMPRESSIBLE .and. dt_cap > dt .and. dt_cap < 1.0e6_wp*dt) &
      dt = dt_cap/real(ceiling(dt_cap/dt*(1.0_wp - 1.0e-12_wp)), wp)
    dt = min(dt, dt_cap)
    if (.not. (dt > 0.0_wp)) then
      call st%set(CPDI_ERR_STATE, 'time step is zero; check material moduli and densities')
      return
    end if
    proj = s%opt%projection /= PROJ_NONE
    if (s%opt%fluid == FLUID_INCOMPRESSIBLE) then
      call incomp_step(s%inc, s%g, s%p, s%opt%flip, s%opt%gravity, dt, s%steps, s%diag, s%timers, s%smax, st)
      if (.not. st%ok()) return
      s%diag(11) = s%smax
      s%dt_last = dt
      call advance_clock(s, dt)
      return
    end if

    ! One parallel region per step: every phase is orphaned worksharing (cpdi_schedule),
    ! serial pieces run in `single`, timers on the master thread. The locals passed to
    ! step_phases are shared in the region; a failing phase returns from every thread (all
    ! see the same st after the phase's barrier).
    nthr = 1
    !$ nthr = max(1, min(omp_get_max_threads(), s%p%n/max(1, s%min_per_thread)))
    !$omp parallel default(shared) num_threads(nthr)
    call step_phases(s, dt, proj, st, bad, fail, buf, t0)
    !$omp end parallel
    if (.not. st%ok()) return
    call advance_clock(s, dt)
  end subroutine sim_step

  subroutine step_phases(s, dt, proj, st, bad, fail, buf, t0)
    !! The phases of sim_step, called by every thread of its parallel region. bad, fail,
    !! buf and t0 are sim_step's (shared) work variables.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    logical, intent(in) :: proj
    type(status_t), intent(inout) :: st
    integer(ik), intent(inout) :: bad, fail
    character(len=*), intent(inout) :: buf
    integer(int64), intent(inout) :: t0
    call tic_master(t0)
    call shape_compute(s%g, s%p, s%sh, bad, fail, st)
    if (.not. all_ok(st)) return
    if (all_int(bad) /= 0) then
      !$omp single
      if (fail == SHAPE_FAIL_INVERTED) then
        write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', s%steps + 1, ': CPDI domain of particle ', bad, &
          ' at (', s%p%x(:, bad), ') is inverted (r1 x r2 <= 0); reduce cfl or refine the grid'
        call st%set(CPDI_ERR_DOMAIN, trim(buf))
      else
        write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', s%steps + 1, ': particle ', bad, ' at (', &
          s%p%x(:, bad), ') has left the grid; enlarge [grid] size, close the wall, '// &
          'or enable domain_scaling for stretched CPDI domains'
        call st%set(CPDI_ERR_OUTSIDE, trim(buf))
      end if
      !$omp end single
      return
    end if
    call strips_build(s%sp, s%sh%row, s%sh%span)
    !$omp single
    call node_range(s)
    !$omp end single
    call toc_master(s, 1, t0)
    if (proj) then   ! the operator of this step's configuration, for both projections
      call projection_setup(s%proj, s%opt%projection, s%opt%shape, s%g, s%p, s%pmask, st, s%sp)
      call toc_master(s, 7, t0)
      if (.not. all_ok(st)) return
    end if

    call p2g(s)
    call toc_master(s, 2, t0)
    call grid_update(s, dt)
    call toc_master(s, 3, t0)
    call g2p(s, dt)
    call toc_master(s, 4, t0)
    call deformation_update(s, dt, st)
    call toc_master(s, 5, t0)
    if (.not. all_ok(st)) return
    if (proj) then
      call projection_apply(s%proj, s%opt%shape, s%g, s%p, s%pmask, s%p%work(1, :), st, s%sp)
      call toc_master(s, 7, t0)
      if (.not. all_ok(st)) return
      call projected_deformation(s)
      call toc_master(s, 5, t0)
    end if
    !$omp single
    s%dt_last = dt
    !$omp end single
    call stress_update(s, st)
    call toc_master(s, 6, t0)
    if (.not. all_ok(st)) return
    if (proj) then
      call project_mean_stress(s, st)
      call toc_master(s, 7, t0)
    end if
  end subroutine step_phases

  subroutine advance_clock(s, dt)
    !! The clock and step counter after a step of dt.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    s%t = s%t + dt
    s%steps = s%steps + 1
    s%diag(1) = s%t
    s%diag(2) = dt
    s%diag(3) = real(s%steps, wp)
  end subroutine advance_clock

  subroutine node_range(s)
    !! The nodes a step has to clear and update: the node rows this step's stencils span,
    !! joined with the last step's. Every grid array is zero outside the rows of the last
    !! step's stencils, so whole-grid loops over s%kw give the same values as over the grid.
    type(sim_t), intent(inout) :: s
    integer(ik) :: kn(2), nn1
    nn1 = s%g%nn(1)
    kn(1) = s%sp%rlo*nn1 + 1
    kn(2) = min((s%sp%rhi + s%sh%span + 1)*nn1, s%g%nnodes)
    s%kw = [max(1_ik, min(kn(1), s%kprev(1))), min(s%g%nnodes, max(kn(2), s%kprev(2)))]
    s%kprev = kn
  end subroutine node_range

  subroutine p2g(s)
    !! Scatter mass, momentum and force to the nodes of each particle's velocity field
    !! (and the mass gradient, for contact normals, when there are several fields), strip
    !! colour by colour (cpdi_schedule).
    type(sim_t), intent(inout) :: s
    integer(ik) :: k, b, colour
    logical :: simple

    !$omp do schedule(static) private(k)
    do k = s%kw(1), s%kw(2)
      s%g%m(k, :) = 0.0_wp
      s%g%px(k, :) = 0.0_wp
      s%g%py(k, :) = 0.0_wp
      s%g%fx(k, :) = 0.0_wp
      s%g%fy(k, :) = 0.0_wp
    end do
    !$omp end do nowait
    !$omp single
    if (s%any_rigid) then
      s%g%mr = 0.0_wp
      s%g%prx = 0.0_wp
      s%g%pry = 0.0_wp
    end if
    if (s%g%nf > 1) then
      s%g%gmx = 0.0_wp
      s%g%gmy = 0.0_wp
      s%g%gv = 0.0_wp
    end if
    !$omp end single
    simple = s%g%nf == 1 .and. .not. s%any_rigid
    do colour = 1, 2
      !$omp do schedule(dynamic, 1) private(b)
      do b = colour, s%sp%nstrip, 2
        if (simple) then
          call p2g_strip_simple(s%sp%perm(s%sp%start(b):s%sp%start(b + 1) - 1), s%sh%nm, s%sh%ns - s%sh%nm, &
                                s%sh%ovf, s%sh%idx, s%sh%w, s%sh%gx, s%sh%gy, s%sh%pidx, s%sh%pw, s%sh%pgx, &
                                s%sh%pgy, s%p%m, s%p%v, s%p%vol, s%p%sig, s%p%bf, s%opt%gravity, s%g%m, s%g%px, &
                                s%g%py, s%g%fx, s%g%fy)
        else
          call p2g_strip(s, s%sp%start(b), s%sp%start(b + 1) - 1)
        end if
      end do
      !$omp end do
    end do
  end subroutine p2g

  subroutine p2g_strip_simple(perm, nm, np, ovf, idx, w, gx, gy, pidx, pw, pgx, pgy, pm, pv, pvol, psig, pbf, &
                              grav, m, px, py, fx, fy)
    !! P2G of the particles perm (one strip) for one velocity field without rigid
    !! particles (the common case): plain arrays, so the compiler knows nothing aliases.
    !! Main slots (nm per particle), then the particle's pool column (np slots), if any.
    integer(ik), intent(in) :: perm(:), nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: w(nm, *), gx(nm, *), gy(nm, *), pw(np, *), pgx(np, *), pgy(np, *), pm(*), pv(2, *), &
                            pvol(*), psig(4, *), pbf(2, *), grav(2)
    real(wp), intent(inout) :: m(*), px(*), py(*), fx(*), fy(*)
    integer(ik) :: i, ip, j
    real(wp) :: mp, mvx, mvy, sxx, syy, sxy, bx, by
    do i = 1, size(perm)
      ip = perm(i)
      mp = pm(ip)
      mvx = mp*pv(1, ip)
      mvy = mp*pv(2, ip)
      sxx = pvol(ip)*psig(1, ip)
      syy = pvol(ip)*psig(2, ip)
      sxy = pvol(ip)*psig(3, ip)
      bx = mp*(grav(1) + pbf(1, ip))
      by = mp*(grav(2) + pbf(2, ip))
      call p2g_slots(nm, idx(:, ip), w(:, ip), gx(:, ip), gy(:, ip))
      j = ovf(ip)
      if (j /= 0) call p2g_slots(np, pidx(:, j), pw(:, j), pgx(:, j), pgy(:, j))
    end do
  contains
    subroutine p2g_slots(ns, idx, w, gx, gy)
      !! Scatter of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: w(ns), gx(ns), gy(ns)
      integer(ik) :: a, k
      real(wp) :: wk, gxk, gyk
      do a = 1, ns
        k = idx(a)
        wk = w(a)
        gxk = gx(a)
        gyk = gy(a)
        m(k) = m(k) + wk*mp
        px(k) = px(k) + wk*mvx
        py(k) = py(k) + wk*mvy
        fx(k) = fx(k) - (sxx*gxk + sxy*gyk) + wk*bx
        fy(k) = fy(k) - (sxy*gxk + syy*gyk) + wk*by
      end do
    end subroutine p2g_slots
  end subroutine p2g_strip_simple

  subroutine p2g_strip(s, m0, m1)
    !! P2G of the particles perm(m0:m1) (one strip).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: m0, m1
    integer(ik) :: m, ip, k, a, f
    real(wp) :: mp, mvx, mvy, vol, sxx, syy, sxy, bx, by, wk, gxk, gyk, wm
    logical :: rig, multi

    multi = s%g%nf > 1
    associate (g => s%g, p => s%p, sh => s%sh)
      do m = m0, m1
        ip = s%sp%perm(m)
        f = s%field(ip)
        mp = p%m(ip)
        mvx = mp*p%v(1, ip)
        mvy = mp*p%v(2, ip)
        vol = p%vol(ip)
        sxx = vol*p%sig(1, ip)
        syy = vol*p%sig(2, ip)
        sxy = vol*p%sig(3, ip)
        bx = mp*(s%opt%gravity(1) + p%bf(1, ip))
        by = mp*(s%opt%gravity(2) + p%bf(2, ip))
        rig = s%rigid(p%mat(ip))
        do a = 1, shape_count(sh, ip)
          call shape_slot(sh, ip, a, k, wk, gxk, gyk)
          wm = wk*mp
          g%m(k, f) = g%m(k, f) + wm
          g%px(k, f) = g%px(k, f) + wk*mvx
          g%py(k, f) = g%py(k, f) + wk*mvy
          g%fx(k, f) = g%fx(k, f) - (sxx*gxk + sxy*gyk) + wk*bx
          g%fy(k, f) = g%fy(k, f) - (sxy*gxk + syy*gyk) + wk*by
          if (rig) then
            g%mr(k, f) = g%mr(k, f) + wm
            g%prx(k, f) = g%prx(k, f) + wk*mvx
            g%pry(k, f) = g%pry(k, f) + wk*mvy
          end if
          if (multi) then
            g%gmx(k, f) = g%gmx(k, f) + mp*gxk
            g%gmy(k, f) = g%gmy(k, f) + mp*gyk
            g%gv(k, f) = g%gv(k, f) + wk*vol
          end if
        end do
      end do
    end associate
  end subroutine p2g_strip

  subroutine grid_update(s, dt)
    !! Nodal velocities at t^n (stored back in px, py) and t^{n+1} (vx, vy), per field;
    !! rigid nodes, walls, and (with several fields) contact at both stages.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik) :: k, f
    real(wp) :: rm, fx, fy, alpha

    alpha = s%opt%damping
    associate (g => s%g)
      call momentum_to_velocity(g, s%mtol, s%kw, g%px, g%py)
      if (s%any_rigid) then
        !$omp single
        call impose_rigid(g, g%px, g%py)
        !$omp end single
      end if
      ! Contact corrects the integrated velocity only: the FLIP increment v^{n+1} - v^n then
      ! carries the whole contact impulse to the particles (a correction of v^n would be lost
      ! to them and let approaching bodies keep kinetic energy the grid no longer has).
      do f = 1, g%nf
        !$omp do schedule(static) private(k, rm, fx, fy)
        do k = s%kw(1), s%kw(2)
          if (g%m(k, f) > s%mtol) then
            rm = 1.0_wp/g%m(k, f)
            fx = g%fx(k, f)
            fy = g%fy(k, f)
            if (alpha > 0.0_wp) then
              fx = fx - alpha*abs(fx)*sign(1.0_wp, g%px(k, f))
              fy = fy - alpha*abs(fy)*sign(1.0_wp, g%py(k, f))
            end if
            g%vx(k, f) = g%px(k, f) + dt*fx*rm
            g%vy(k, f) = g%py(k, f) + dt*fy*rm
          else
            g%vx(k, f) = 0.0_wp
            g%vy(k, f) = 0.0_wp
          end if
        end do
        !$omp end do
      end do
      !$omp single
      if (s%any_rigid) call impose_rigid(g, g%vx, g%vy)
      do f = 1, g%nf
        call walls_of_field(s, f, g%px(:, f), g%py(:, f))
        call walls_of_field(s, f, g%vx(:, f), g%vy(:, f))
      end do
      if (g%nf > 1) then
        call contact_correct(g, g%vx, g%vy, s%mtol, s%friction, s%fullness*g%h**2, s%field_rigid, s%diag(13))
        do f = 1, g%nf
          call walls_of_field(s, f, g%vx(:, f), g%vy(:, f))
        end do
      end if
      !$omp end single
    end associate
  end subroutine grid_update

  subroutine walls_of_field(s, f, vx, vy)
    !! Wall conditions on field f. With contact, walls meet solid bodies under the bodies'
    !! volume constraint (a stiff body lands on the floor, not a cell above it: see
    !! grid_apply_walls); fluids, and every run without contact, are held wherever they
    !! reach a wall node.
    type(sim_t), intent(in) :: s
    integer(ik), intent(in) :: f
    real(wp), intent(inout) :: vx(:), vy(:)
    if (s%field_solid(f)) then
      call grid_apply_walls(s%g, vx, vy, s%g%gv(:, f), s%fullness*s%g%h**2)
    else
      call grid_apply_walls(s%g, vx, vy)
    end if
  end subroutine walls_of_field

  subroutine momentum_to_velocity(g, mtol, kw, qx, qy)
    !! In place: nodal momentum (qx, qy) of every field -> velocity q/m on nodes kw(1)..kw(2);
    !! nodes lighter than mtol carry no velocity.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: mtol
    integer(ik), intent(in) :: kw(2)
    real(wp), intent(inout) :: qx(:, :), qy(:, :)
    integer(ik) :: k, f
    real(wp) :: rm
    do f = 1, g%nf
      !$omp do schedule(static) private(k, rm)
      do k = kw(1), kw(2)
        if (g%m(k, f) > mtol) then
          rm = 1.0_wp/g%m(k, f)
          qx(k, f) = qx(k, f)*rm
          qy(k, f) = qy(k, f)*rm
        else
          qx(k, f) = 0.0_wp
          qy(k, f) = 0.0_wp
        end if
      end do
      !$omp end do
    end do
  end subroutine momentum_to_velocity

  subroutine impose_rigid(g, vx, vy)
    !! Nodes touched by rigid particles move with them (clamped body), field by field.
    type(grid_t), intent(in) :: g
    real(wp), intent(inout) :: vx(:, :), vy(:, :)
    integer(ik) :: k, f
    do f = 1, g%nf
      do k = 1, g%nnodes
        if (g%mr(k, f) > 0.0_wp) then
          vx(k, f) = g%prx(k, f)/g%mr(k, f)
          vy(k, f) = g%pry(k, f)/g%mr(k, f)
        end if
      end do
    end do
  end subroutine impose_rigid

  subroutine g2p(s, dt)
    !! Particle velocity (FLIP/PIC blend), position, and velocity gradient, each particle
    !! from its own velocity field; diagnostics summed block by block.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik) :: c, lo, hi
    logical :: musl, simple

    musl = s%opt%update == UPDATE_MUSL
    simple = s%g%nf == 1 .and. .not. s%any_rigid
    !$omp do schedule(dynamic, 1) private(c, lo, hi)
    do c = 1, NCHUNK
      call chunk_range(c, s%p%n, lo, hi)
      if (simple) then
        call g2p_block_simple(lo, hi, s%sh%nm, s%sh%ns - s%sh%nm, s%sh%ovf, s%sh%idx, s%sh%w, s%sh%pidx, &
                              s%sh%pw, s%g%vx, s%g%vy, s%g%px, s%g%py, s%p%m, s%p%v, s%p%x, s%p%bf, s%opt%flip, &
                              dt, s%opt%gravity, s%g%origin, s%g%origin + real(s%g%ncell, wp)*s%g%h, &
                              s%g%walls /= WALL_OPEN, s%red(:, c))
        if (.not. musl) call vgrad_block(lo, hi, s%sh, s%g%vx, s%g%vy, s%p%L)
      else
        call g2p_block(s, dt, lo, hi, s%red(:, c))
      end if
    end do
    !$omp end do
    !$omp single
    s%diag(4) = sum(s%red(1, :))
    s%diag(6) = sum(s%red(2, :))
    s%diag(7) = sum(s%red(3, :))
    s%diag(8) = s%diag(8) + sum(s%red(4, :))
    s%diag(9) = s%diag(9) + sum(s%red(5, :))
    s%diag(12) = sum(s%red(6, :))
    !$omp end single nowait
    ! With several fields (contact) the velocity gradient comes from the contact-corrected
    ! integrated velocity, the field that moved the particles: a MUSL remap of the
    ! particle momenta near a contact surface feeds approach velocity that contact
    ! removed back into the strain rate (measured: +37 % kinetic energy in a head-on
    ! collision of two elastic bars).
    if (musl .and. s%g%nf == 1) call musl_remap(s)
  end subroutine g2p

  subroutine g2p_block(s, dt, lo, hi, red)
    !! G2P of particles lo..hi; red = [kinetic energy, momentum x, y, work of gravity,
    !! work of body forces, wall clamps] of the block.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(out) :: red(6)
    integer(ik) :: ip, k, a, nclamp, f
    real(wp) :: dvx, dvy, vnx, vny, wk, gxk, gyk, flip, xo(2), xmin(2), xmax(2), ke, mom(2), wg, wb, mp
    logical :: musl, closed(4)

    flip = s%opt%flip
    musl = s%opt%update == UPDATE_MUSL
    xmin = s%g%origin
    xmax = s%g%origin + real(s%g%ncell, wp)*s%g%h
    closed = s%g%walls /= WALL_OPEN
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    wb = 0.0_wp
    nclamp = 0
    associate (g => s%g, p => s%p, sh => s%sh)
      do ip = lo, hi
        mp = p%m(ip)
        xo = p%x(:, ip)
        f = s%field(ip)
        if (s%rigid(p%mat(ip))) then
          p%v(:, ip) = s%mats(p%mat(ip))%vel
          p%x(:, ip) = xo + dt*p%v(:, ip)
          p%L(:, ip) = 0.0_wp
        else
          dvx = 0.0_wp
          dvy = 0.0_wp
          vnx = 0.0_wp
          vny = 0.0_wp
          do a = 1, shape_count(sh, ip)
            call shape_slot(sh, ip, a, k, wk, gxk, gyk)
            vnx = vnx + wk*g%vx(k, f)
            vny = vny + wk*g%vy(k, f)
            dvx = dvx + wk*(g%vx(k, f) - g%px(k, f))
            dvy = dvy + wk*(g%vy(k, f) - g%py(k, f))
          end do
          p%v(1, ip) = flip*(p%v(1, ip) + dvx) + (1.0_wp - flip)*vnx
          p%v(2, ip) = flip*(p%v(2, ip) + dvy) + (1.0_wp - flip)*vny
          p%x(1, ip) = xo(1) + dt*vnx
          p%x(2, ip) = xo(2) + dt*vny
          if (.not. musl .or. g%nf > 1) p%L(:, ip) = velocity_gradient(sh, g%vx(:, f), g%vy(:, f), ip)
          call hold_on_walls(p%x(:, ip), xmin, xmax, closed, nclamp)
        end if
        ke = ke + 0.5_wp*mp*(p%v(1, ip)**2 + p%v(2, ip)**2)
        mom = mom + mp*p%v(:, ip)
        wg = wg + mp*dot_product(s%opt%gravity, p%x(:, ip) - xo)
        wb = wb + mp*dot_product(p%bf(:, ip), p%x(:, ip) - xo)
      end do
    end associate
    red = [ke, mom(1), mom(2), wg, wb, real(nclamp, wp)]
  end subroutine g2p_block

  subroutine g2p_block_simple(lo, hi, nm, np, ovf, idx, w, pidx, pw, vx, vy, vnx0, vny0, pm, pv, px, pbf, flip, &
                              dt, grav, xmin, xmax, closed, red)
    !! g2p_block for one velocity field without rigid particles (the common case), on plain
    !! arrays; the same arithmetic in the same order (main slots, then the pool column).
    !! vnx0, vny0: nodal velocity at t^n.
    integer(ik), intent(in) :: lo, hi, nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: w(nm, *), pw(np, *), vx(*), vy(*), vnx0(*), vny0(*), pm(*), pbf(2, *), flip, dt, &
                            grav(2), xmin(2), xmax(2)
    real(wp), intent(inout) :: pv(2, *), px(2, *)
    logical, intent(in) :: closed(4)
    real(wp), intent(out) :: red(6)
    integer(ik) :: ip, j, nclamp
    real(wp) :: dvx, dvy, vnx, vny, xo(2), ke, mom(2), wg, wb, mp
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    wb = 0.0_wp
    nclamp = 0
    do ip = lo, hi
      mp = pm(ip)
      xo = px(:, ip)
      dvx = 0.0_wp
      dvy = 0.0_wp
      vnx = 0.0_wp
      vny = 0.0_wp
      call g2p_slots(nm, idx(:, ip), w(:, ip))
      j = ovf(ip)
      if (j /= 0) call g2p_slots(np, pidx(:, j), pw(:, j))
      pv(1, ip) = flip*(pv(1, ip) + dvx) + (1.0_wp - flip)*vnx
      pv(2, ip) = flip*(pv(2, ip) + dvy) + (1.0_wp - flip)*vny
      px(1, ip) = xo(1) + dt*vnx
      px(2, ip) = xo(2) + dt*vny
      call hold_on_walls(px(:, ip), xmin, xmax, closed, nclamp)
      ke = ke + 0.5_wp*mp*(pv(1, ip)**2 + pv(2, ip)**2)
      mom = mom + mp*pv(:, ip)
      wg = wg + mp*dot_product(grav, px(:, ip) - xo)
      wb = wb + mp*dot_product(pbf(:, ip), px(:, ip) - xo)
    end do
    red = [ke, mom(1), mom(2), wg, wb, real(nclamp, wp)]
  contains
    subroutine g2p_slots(ns, idx, w)
      !! Gather of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: w(ns)
      integer(ik) :: a, k
      real(wp) :: wk
      do a = 1, ns
        k = idx(a)
        wk = w(a)
        vnx = vnx + wk*vx(k)
        vny = vny + wk*vy(k)
        dvx = dvx + wk*(vx(k) - vnx0(k))
        dvy = dvy + wk*(vy(k) - vny0(k))
      end do
    end subroutine g2p_slots
  end subroutine g2p_block_simple

  subroutine vgrad_block(lo, hi, sh, vx, vy, l)
    !! Velocity gradient of particles lo..hi from one nodal velocity field (the same sums as
    !! velocity_gradient), main slots then pool column on plain arrays (vgrad_plain).
    !! The general paths keep velocity_gradient: calling this from them changes contact runs
    !! in the last bits (the compiler vectorises these sums without FMA contraction), so
    !! merging the two needs its own gold regeneration.
    integer(ik), intent(in) :: lo, hi
    type(shape_t), intent(in) :: sh
    real(wp), intent(in) :: vx(*), vy(*)
    real(wp), intent(inout) :: l(4, *)
    call vgrad_plain(lo, hi, sh%nm, sh%ns - sh%nm, sh%ovf, sh%idx, sh%gx, sh%gy, sh%pidx, sh%pgx, sh%pgy, vx, vy, l)
  end subroutine vgrad_block

  subroutine vgrad_plain(lo, hi, nm, np, ovf, idx, gx, gy, pidx, pgx, pgy, vx, vy, l)
    !! vgrad_block on plain arrays: nm main slots per particle, np in its pool column.
    integer(ik), intent(in) :: lo, hi, nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: gx(nm, *), gy(nm, *), pgx(np, *), pgy(np, *), vx(*), vy(*)
    real(wp), intent(inout) :: l(4, *)
    integer(ik) :: ip, j
    real(wp) :: l1, l2, l3, l4
    do ip = lo, hi
      l1 = 0.0_wp
      l2 = 0.0_wp
      l3 = 0.0_wp
      l4 = 0.0_wp
      call vgrad_slots(nm, idx(:, ip), gx(:, ip), gy(:, ip))
      j = ovf(ip)
      if (j /= 0) call vgrad_slots(np, pidx(:, j), pgx(:, j), pgy(:, j))
      l(:, ip) = [l1, l2, l3, l4]
    end do
  contains
    subroutine vgrad_slots(ns, idx, gx, gy)
      !! Sums of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: gx(ns), gy(ns)
      integer(ik) :: a, k
      do a = 1, ns
        k = idx(a)
        l1 = l1 + vx(k)*gx(a)
        l2 = l2 + vy(k)*gx(a)
        l3 = l3 + vx(k)*gy(a)
        l4 = l4 + vy(k)*gy(a)
      end do
    end subroutine vgrad_slots
  end subroutine vgrad_plain

  subroutine remap_strip_simple(perm, nm, np, ovf, idx, w, pidx, pw, pm, pv, qx, qy)
    !! MUSL momentum scatter of the particles perm (one strip) to one field, plain arrays
    !! (main slots, then the pool column).
    integer(ik), intent(in) :: perm(:), nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: w(nm, *), pw(np, *), pm(*), pv(2, *)
    real(wp), intent(inout) :: qx(*), qy(*)
    integer(ik) :: i, ip, j
    real(wp) :: mvx, mvy
    do i = 1, size(perm)
      ip = perm(i)
      mvx = pm(ip)*pv(1, ip)
      mvy = pm(ip)*pv(2, ip)
      call remap_slots(nm, idx(:, ip), w(:, ip))
      j = ovf(ip)
      if (j /= 0) call remap_slots(np, pidx(:, j), pw(:, j))
    end do
  contains
    subroutine remap_slots(ns, idx, w)
      !! Scatter of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: w(ns)
      integer(ik) :: a, k
      do a = 1, ns
        k = idx(a)
        qx(k) = qx(k) + w(a)*mvx
        qy(k) = qy(k) + w(a)*mvy
      end do
    end subroutine remap_slots
  end subroutine remap_strip_simple

  pure function velocity_gradient(sh, vx, vy, ip) result(l)
    !! L_p = sum_i v_i (x) grad S_ip, layout [L11, L21, L12, L22].
    type(shape_t), intent(in) :: sh
    real(wp), intent(in) :: vx(:), vy(:)
    integer(ik), intent(in) :: ip
    real(wp) :: l(4)
    integer(ik) :: a, k
    real(wp) :: wk, gxk, gyk
    l = 0.0_wp
    do a = 1, shape_count(sh, ip)
      call shape_slot(sh, ip, a, k, wk, gxk, gyk)
      l(1) = l(1) + vx(k)*gxk
      l(2) = l(2) + vy(k)*gxk
      l(3) = l(3) + vx(k)*gyk
      l(4) = l(4) + vy(k)*gyk
    end do
  end function velocity_gradient

  subroutine musl_remap(s)
    !! MUSL: map the updated particle momentum back to the grid and take the velocity
    !! gradient from that field (Sulsky et al. 1994); rigid nodes and walls apply. Not
    !! used with contact (see g2p).
    type(sim_t), intent(inout) :: s
    integer(ik) :: ip, k, f, b, colour, c, lo, hi
    !$omp do schedule(static) private(k)
    do k = s%kw(1), s%kw(2)
      s%g%vx(k, :) = 0.0_wp
      s%g%vy(k, :) = 0.0_wp
    end do
    !$omp end do
    do colour = 1, 2
      !$omp do schedule(dynamic, 1) private(b)
      do b = colour, s%sp%nstrip, 2
        if (s%g%nf == 1) then
          call remap_strip_simple(s%sp%perm(s%sp%start(b):s%sp%start(b + 1) - 1), s%sh%nm, s%sh%ns - s%sh%nm, &
                                  s%sh%ovf, s%sh%idx, s%sh%w, s%sh%pidx, s%sh%pw, s%p%m, s%p%v, s%g%vx, s%g%vy)
        else
          call remap_strip(s, s%sp%start(b), s%sp%start(b + 1) - 1)
        end if
      end do
      !$omp end do
    end do
    call momentum_to_velocity(s%g, s%mtol, s%kw, s%g%vx, s%g%vy)
    !$omp single
    if (s%any_rigid) call impose_rigid(s%g, s%g%vx, s%g%vy)
    do f = 1, s%g%nf
      call grid_apply_walls(s%g, s%g%vx(:, f), s%g%vy(:, f))
    end do
    !$omp end single
    !$omp do schedule(dynamic, 1) private(c, lo, hi, ip, f)
    do c = 1, NCHUNK
      call chunk_range(c, s%p%n, lo, hi)
      if (s%g%nf == 1 .and. .not. s%any_rigid) then
        call vgrad_block(lo, hi, s%sh, s%g%vx, s%g%vy, s%p%L)
        cycle
      end if
      do ip = lo, hi
        if (s%rigid(s%p%mat(ip))) cycle
        f = s%field(ip)
        s%p%L(:, ip) = velocity_gradient(s%sh, s%g%vx(:, f), s%g%vy(:, f), ip)
      end do
    end do
    !$omp end do
  end subroutine musl_remap

  subroutine remap_strip(s, m0, m1)
    !! MUSL momentum scatter of the particles perm(m0:m1) (one strip).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: m0, m1
    integer(ik) :: m, ip, k, a, f
    real(wp) :: mvx, mvy, wk, gxk, gyk
    associate (g => s%g, p => s%p, sh => s%sh)
      do m = m0, m1
        ip = s%sp%perm(m)
        f = s%field(ip)
        mvx = p%m(ip)*p%v(1, ip)
        mvy = p%m(ip)*p%v(2, ip)
        do a = 1, shape_count(sh, ip)
          call shape_slot(sh, ip, a, k, wk, gxk, gyk)
          g%vx(k, f) = g%vx(k, f) + wk*mvx
          g%vy(k, f) = g%vy(k, f) + wk*mvy
        end do
      end do
    end associate
  end subroutine remap_strip

  subroutine deformation_update(s, dt, st)
    !! F <- (I + dt L) F, volume J V0, CPDI domains r = F r0 (optionally scaled). With the
    !! projection on, the volumetric strain increment ln det(I + dt L) of the participating
    !! particles is left in work(1, :) for projection (rate form, Mast et al. 2012) and
    !! `projected_deformation` rebuilds J, F and the domains from it.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    type(status_t), intent(inout) :: st
    integer(ik) :: c, lo, hi, ip
    character(len=300) :: buf

    !$omp do schedule(dynamic, 1) private(c, lo, hi)
    do c = 1, NCHUNK
      call chunk_range(c, s%p%n, lo, hi)
      call deformation_block(s, dt, lo, hi, s%cbad(c), s%cval(c))
    end do
    !$omp end do
    !$omp single
    do c = 1, NCHUNK
      ip = s%cbad(c)
      if (ip == 0) cycle
      if (s%cval(c) /= s%cval(c)) then
        write (buf, '(a,i0,a,i0,a)') 'step ', s%steps + 1, ': NaN in the velocity gradient of particle ', &
          ip, '; the run became unstable (reduce cfl, check material parameters)'
        call st%set(CPDI_ERR_NAN, trim(buf))
      else
        write (buf, '(a,i0,a,i0,a,2es12.4,a,es11.3,a)') 'step ', s%steps + 1, ': particle ', ip, ' at (', &
          s%p%x(:, ip), ') has det F = ', s%cval(c), ' <= 0 (material inverted); reduce cfl or refine the grid'
        call st%set(CPDI_ERR_JACOBIAN, trim(buf))
      end if
      exit
    end do
    !$omp end single
  end subroutine deformation_update

  subroutine deformation_block(s, dt, lo, hi, bad, jbad)
    !! deformation_update of particles lo..hi; bad is the first particle with det F <= 0
    !! or NaN (0 if none) and jbad its det F.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik), intent(in) :: lo, hi
    integer(ik), intent(out) :: bad
    real(wp), intent(out) :: jbad
    integer(ik) :: ip
    real(wp) :: a11, a21, a12, a22, f(4), j, deta
    logical :: proj

    proj = s%opt%projection /= PROJ_NONE
    bad = 0
    jbad = 0.0_wp
    associate (p => s%p)
      do ip = lo, hi
        a11 = 1.0_wp + dt*p%L(1, ip)
        a21 = dt*p%L(2, ip)
        a12 = dt*p%L(3, ip)
        a22 = 1.0_wp + dt*p%L(4, ip)
        deta = a11*a22 - a12*a21
        f = p%F(:, ip)
        if (s%fluid(p%mat(ip))) then
          ! a fluid has no memory of shear: keep only its volume ratio, F = sqrt(J) I
          j = det2(f)*deta
          p%F(:, ip) = [sqrt(max(j, 0.0_wp)), 0.0_wp, 0.0_wp, sqrt(max(j, 0.0_wp))]
        else
          p%F(1, ip) = a11*f(1) + a12*f(2)
          p%F(2, ip) = a21*f(1) + a22*f(2)
          p%F(3, ip) = a11*f(3) + a12*f(4)
          p%F(4, ip) = a21*f(3) + a22*f(4)
          j = det2(p%F(:, ip))
        end if
        if (.not. (j > 0.0_wp) .or. .not. (deta > 0.0_wp)) then
          if (bad == 0) then
            bad = ip
            jbad = j
            if (deta /= deta) jbad = deta
          end if
          cycle
        end if
        p%vol(ip) = j*p%vol0(ip)
        p%jbar(ip) = j
        if (proj) then
          p%work(1, ip) = log(deta)          ! volumetric strain increment, projected
          p%work(2, ip) = det2(f)            ! J at the start of the step
          p%work(3, ip) = p%work(1, ip)      ! raw increment, for the stabilisation
        end if
      end do
    end associate
    if (.not. proj .and. bad == 0) call update_domains(s, lo, hi)
  end subroutine deformation_block

  subroutine projected_deformation(s)
    !! J, F and volume of the participating particles from the projected strain increment
    !! (fluids F = sqrt(J) I, solids F <- sqrt(J~/J) F: plane-strain F-bar), then every
    !! domain. Stabilisation: the increment used is (1 - beta) projected + beta raw. A full
    !! projection gives sub-cell (hourglass) motions of a fluid no volumetric stiffness at
    !! all; over seconds they grow and the water collapses into itself (measured: a resting
    !! tank gained 2.7 kJ of kinetic energy in 4 s). beta keeps a stiffness beta K for them.
    type(sim_t), intent(inout) :: s
    integer(ik) :: c, lo, hi, ip
    real(wp) :: jn
    !$omp do schedule(dynamic, 1) private(c, lo, hi, ip, jn)
    do c = 1, NCHUNK
      call chunk_range(c, s%p%n, lo, hi)
      do ip = lo, hi
        if (s%pmask(ip)) then
          jn = s%p%work(2, ip)*exp((1.0_wp - s%opt%pstab)*s%p%work(1, ip) + s%opt%pstab*s%p%work(3, ip))
          if (s%fluid(s%p%mat(ip))) then
            s%p%F(:, ip) = [sqrt(jn), 0.0_wp, 0.0_wp, sqrt(jn)]
          else
            s%p%F(:, ip) = s%p%F(:, ip)*sqrt(jn/s%p%jbar(ip))
          end if
          s%p%vol(ip) = jn*s%p%vol0(ip)
          s%p%jbar(ip) = jn
        end if
      end do
      call update_domains(s, lo, hi)
    end do
    !$omp end do
  end subroutine projected_deformation

  subroutine update_domains(s, lo, hi)
    !! CPDI domains of particles lo..hi from their F (domain_block).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: lo, hi
    if (s%opt%shape /= SHAPE_CPDI) return
    call domain_block(lo, hi, s%p%F, s%p%r0, s%opt%domain_scaling == 1, s%opt%lcrit*s%g%h, s%p%r)
  end subroutine update_domains

  subroutine domain_block(lo, hi, f, r0, scaled, lc, r)
    !! r = F r0 (map_domains) for particles lo..hi, with optional Homel et al. (2016)
    !! scaling: diagonals longer than lc are shortened to lc.
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(in) :: f(4, *), r0(4, *), lc
    logical, intent(in) :: scaled
    real(wp), intent(inout) :: r(4, *)
    integer(ik) :: ip
    real(wp) :: la(2), lb(2), na, nb
    call map_domains(lo, hi, f, r0, r)
    if (.not. scaled) return
    do ip = lo, hi
      la = r(1:2, ip) + r(3:4, ip)
      lb = r(1:2, ip) - r(3:4, ip)
      na = norm2(la)
      nb = norm2(lb)
      if (na > lc .or. nb > lc) then
        if (na > lc) la = la*(lc/na)
        if (nb > lc) lb = lb*(lc/nb)
        r(1:2, ip) = 0.5_wp*(la + lb)
        r(3:4, ip) = 0.5_wp*(la - lb)
      end if
    end do
  end subroutine domain_block

  subroutine stress_update(s, st)
    !! Stress and energy of every particle; signal speed for the next step.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: c, lo, hi, ip
    character(len=300) :: buf

    ! max signal speed and min viscous step per block (cext), reduced in the single: max
    ! and min are exact, so this is the value of any other reduction order.
    !$omp do schedule(dynamic, 1) private(c, lo, hi)
    do c = 1, NCHUNK
      call chunk_range(c, s%p%n, lo, hi)
      s%cext(:, c) = [0.0_wp, huge(1.0_wp)]
      call stress_block(s, lo, hi, s%red(:, c), s%cext(1, c), s%cext(2, c), s%cbad(c))
    end do
    !$omp end do
    !$omp single
    do c = 1, NCHUNK
      ip = s%cbad(c)
      if (ip == 0) cycle
      write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', s%steps + 1, ': NaN or Inf in the stress or velocity '// &
        'of particle ', ip, ' at (', s%p%x(:, ip), '); the run became unstable (reduce cfl, check materials)'
      call st%set(CPDI_ERR_NAN, trim(buf))
      exit
    end do
    if (st%ok()) then
      s%diag(5) = sum(s%red(1, :))
      s%diag(14) = s%diag(14) + sum(s%red(2, :))*s%dt_last
      s%smax = maxval(s%cext(1, :))
      s%visc_dt = minval(s%cext(2, :))
      s%diag(11) = s%smax
    end if
    !$omp end single
  end subroutine stress_update

  subroutine stress_block(s, lo, hi, red, smax, vdt, bad)
    !! Stress of particles lo..hi; red(1:2) = [strain energy, viscous dissipation rate] of
    !! the block; smax, vdt: running max signal speed and min viscous step; bad: the first
    !! particle with a non-finite stress or velocity (0 if none).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(out) :: red(6)
    real(wp), intent(inout) :: smax, vdt
    integer(ik), intent(out) :: bad
    integer(ik) :: ip, im
    real(wp) :: se, c, rho, vmag, sig(4), dis, tr3
    logical :: proj

    proj = s%opt%projection /= PROJ_NONE
    se = 0.0_wp
    dis = 0.0_wp
    bad = 0
    associate (p => s%p)
      call material_stresses(s%mats, s%opt%kinematics, lo, hi, p%mat, p%F, p%L, p%jbar, p%sig, p%psi)
      do ip = lo, hi
        im = p%mat(ip)
        sig = p%sig(:, ip)
        p%psi(ip) = p%psi(ip)*p%vol0(ip)
        se = se + p%psi(ip)
        rho = p%m(ip)/p%vol(ip)
        vmag = sqrt(p%v(1, ip)**2 + p%v(2, ip)**2)
        c = sqrt(s%mats(im)%pmod/rho) + vmag
        if (.not. (abs(sig(1)) + abs(sig(2)) + abs(sig(3)) + c < huge(1.0_wp))) then
          if (bad == 0) bad = ip
          cycle
        end if
        smax = max(smax, c)
        if (proj) then   ! the mean stress, for project_mean_stress
          p%work(1, ip) = (sig(1) + sig(2) + sig(4))/3.0_wp
          p%work(2, ip) = p%work(1, ip)
        end if
        if (s%mats(im)%model == MAT_FLUID .and. s%mats(im)%visc > 0.0_wp) then
          vdt = min(vdt, 0.5_wp*rho*s%g%h**2/s%mats(im)%visc)
          ! viscous dissipation 2 mu dev(D):dev(D) V (plane strain, D_zz = 0)
          tr3 = (p%L(1, ip) + p%L(4, ip))/3.0_wp
          dis = dis + 2.0_wp*s%mats(im)%visc*p%vol(ip)*((p%L(1, ip) - tr3)**2 + (p%L(4, ip) - tr3)**2 + tr3**2 &
                                                        + 0.5_wp*(p%L(2, ip) + p%L(3, ip))**2)
        end if
      end do
    end associate
    red = [se, dis, 0.0_wp, 0.0_wp, 0.0_wp, 0.0_wp]
  end subroutine stress_block

  subroutine project_mean_stress(s, st)
    !! Replace the mean stress (sxx + syy + szz)/3 of the participating particles, left in
    !! work(1:2, :) by stress_update, by its projection (blended with beta of the particle's
    !! own, see projected_deformation); the deviatoric stress is left as it is. Uses the
    !! operator set up for this step.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: c, lo, hi, ip
    real(wp) :: dm
    call projection_apply(s%proj, s%opt%shape, s%g, s%p, s%pmask, s%p%work(1, :), st, s%sp)
    if (.not. st%ok()) return
    !$omp do schedule(dynamic, 1) private(c, lo, hi, ip, dm)
    do c = 1, NCHUNK
      call chunk_range(c, s%p%n, lo, hi)
      do ip = lo, hi
        if (.not. s%pmask(ip)) cycle
        dm = (1.0_wp - s%opt%pstab)*(s%p%work(1, ip) - s%p%work(2, ip))
        s%p%sig(1, ip) = s%p%sig(1, ip) + dm
        s%p%sig(2, ip) = s%p%sig(2, ip) + dm
        s%p%sig(4, ip) = s%p%sig(4, ip) + dm
      end do
    end do
    !$omp end do
  end subroutine project_mean_stress
end module cpdi_step
