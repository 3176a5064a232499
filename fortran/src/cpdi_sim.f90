!> The simulation object: options, state and the helpers every stage of a step shares.
module cpdi_sim
  !! sim_t holds the grid, particles, materials, interpolation, projection and incompressible-water
  !! storage of one simulation, its clock, diagnostics and timers. The stages of a step
  !! (cpdi_transfer, cpdi_grid_update, cpdi_constitutive, cpdi_incompressible) act on it;
  !! cpdi_step puts them in sequence.
  use, intrinsic :: iso_fortran_env, only: int64
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t
  use cpdi_grid, only: grid_t
  use cpdi_particles, only: particles_t
  use cpdi_shape, only: shape_t, SHAPE_GIMP, SHAPE_CPDI
  use cpdi_schedule, only: strips_t, NCHUNK
  use cpdi_materials, only: material_t, KIN_LOG
  use cpdi_projection, only: projection_t, PROJ_NONE
  use cpdi_incompressible, only: incomp_t, FLUID_WEAKLY_COMPRESSIBLE
  use cpdi_motion, only: vtable_t
  use cpdi_loads, only: loads_t
  use cpdi_slots, only: NDIAG, NTIMER
  use cpdi_options, only: optset_t, opt_value, opt_code, opt_index
  implicit none
  private

  integer(ik), parameter, public :: UPDATE_USL = 0
  integer(ik), parameter, public :: UPDATE_MUSL = 1

  public :: NDIAG, NTIMER   !! diagnostics and timers: their slots are named in cpdi_slots
  integer(ik), parameter, public :: MIN_PER_THREAD = 16384
  !! particles per thread below which a step uses fewer threads: a step has about 20
  !! barriers, and a small step on 2 threads can run slower than on 1 (passive waits;
  !! measurements: docs/notes/threads.md). Results do not depend on it.
  !! The environment variable CPDI_MIN_PER_THREAD (read by sim_prepare) replaces it; the
  !! tests set it to 1 so that their small cases really run on several threads.
  integer(ik), parameter, public :: PROBE_MIN = 32    !! steps between probes of the slower team ...
  integer(ik), parameter, public :: PROBE_MAX = 128   !! ... growing to this while probes confirm the choice
  integer(ik), parameter, public :: PROBE_COST = 100  !! ... or further, to PROBE_COST (t_slow / t_fast - 1)
  !! steps, so that a probe of a much slower team costs at most about 1 % of the run: a
  !! 1-thread probe beside a 16-thread team costs some 15 of its steps, 12 % of 128 steps

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
    logical :: devonly = .false.             !! the in-plane deviatoric stress only in the nodal forces (the
                                             !! substeps of solid_substeps = "implicit": the volumetric part is
                                             !! the water step's projection pressure, in the body force aw)
    real(wp) :: sub_t0 = 0.0_wp, sub_dt = 1.0_wp  !! devonly: the water step the substeps run in
    real(wp) :: dt_last = 0.0_wp
    type(shape_t) :: sh
    type(projection_t) :: proj
    type(incomp_t) :: inc                    !! incompressible water: settings and staggered grid
    type(loads_t) :: ld                      !! coupled runs: the water's load on every solid particle
    type(vtable_t), allocatable :: vtab(:)   !! per material: a rigid body's velocity table (cpdi_motion)
    logical, allocatable :: pmask(:)         !! per particle: takes part in the projection
    type(options_t) :: opt                   !! the typed copy of ov the stages read (sim_apply_options)
    type(optset_t) :: ov                     !! every option by name (cpdi_options; the API sets these)
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
    real(wp) :: step_s(2) = 0.0_wp           !! recent wall seconds of a step on 1 thread, on all (0: not measured)
    integer(ik) :: team = 0                  !! the faster team when last chosen (1 or 2; 0: not yet)
    integer(ik) :: since_probe = 0           !! steps since the other team size was last measured
    integer(ik) :: probe_gap = PROBE_MIN     !! steps between probes of the other team (cpdi_step)
    ! Deformable solids coupled to the incompressible water, subcycled at the water's pace
    ! ([solver] solid_substeps): their explicit steps run in `sub`, a simulation of those
    ! particles alone on the same grid, inside each water step (cpdi_step subcycle_solids).
    type(sim_t), pointer :: sub => null()     !! the solids' own simulation (null: none)
    integer(ik), allocatable :: isub(:)       !! per particle of sub: its index here
    integer(ik) :: nsub = 0                   !! sub's deformable particles, isub(1:nsub); prescribed rigid ones follow
    real(wp), allocatable :: xw(:, :)         !! sub's positions at the start of the water step (2, n of sub)
  end type sim_t

  public :: tic, toc, all_ok, all_int, tic_master, toc_master, sim_apply_options

contains

  subroutine sim_apply_options(s)
    !! Copy the options set by name (s%ov, cpdi_options) into the typed fields the stages read.
    !! Only the options older than the table are here; a new option is read where it is used,
    !! opt_value(s%ov, 'name'), and needs no line here.
    type(sim_t), intent(inout) :: s
    s%opt%shape = opt_code(s%ov, 'shape')
    s%opt%update = opt_code(s%ov, 'update')
    s%opt%projection = opt_code(s%ov, 'projection')
    s%opt%kinematics = opt_code(s%ov, 'kinematics')
    s%opt%domain_scaling = opt_code(s%ov, 'domain_scaling')
    s%opt%fixed_dt = opt_code(s%ov, 'fixed_dt')
    s%opt%fluid = opt_code(s%ov, 'fluid')
    s%opt%cfl = opt_value(s%ov, 'cfl')
    s%opt%gravity = s%ov%v(:, opt_index('gravity'))
    s%opt%damping = opt_value(s%ov, 'damping')
    s%opt%dt = opt_value(s%ov, 'dt')
    s%opt%flip = opt_value(s%ov, 'flip')
    s%opt%lcrit = opt_value(s%ov, 'lcrit')
    s%opt%pstab = opt_value(s%ov, 'projection_stabilization')
    s%inc%transfer = opt_code(s%ov, 'transfer')
    s%inc%tol = opt_value(s%ov, 'cg_tolerance')
    s%inc%maxit = opt_code(s%ov, 'cg_max_iterations')
    s%inc%beta = opt_value(s%ov, 'volume_correction')
    s%inc%mc%precond = opt_code(s%ov, 'pressure_precond')
    s%inc%substeps = opt_code(s%ov, 'solid_substeps')
    s%inc%mc%ov = s%ov   ! the pressure stages (cpdi_pressure, cpdi_coupling, cpdi_loads) read options by name
  end subroutine sim_apply_options

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
end module cpdi_sim
