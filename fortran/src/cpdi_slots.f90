!> Named slots: the diagnostics, the phase timers and the rows of the full (checkpoint) state.
module cpdi_slots
  !! Every index into s%diag, s%timers and the full state's particle rows and scalars is a named
  !! constant here, with the name Python knows it by (issue 39 item 1): the API gives the names
  !! (cpdi_slot_count, cpdi_slot_info) and harness.solver builds DIAG_NAMES, TIMER_NAMES,
  !! FULL_STATE_ROWS and FULL_STATE_SCALARS from them at import.
  use cpdi_kinds, only: ik
  implicit none
  private

  integer, parameter, public :: SLOT_NAME_LEN = 24

  ! diagnostics, s%diag
  integer(ik), parameter, public :: DIAG_T = 1                  !! time [s]
  integer(ik), parameter, public :: DIAG_DT = 2                 !! last time step [s]
  integer(ik), parameter, public :: DIAG_STEPS = 3              !! steps taken
  integer(ik), parameter, public :: DIAG_KINETIC = 4            !! kinetic energy [J/m]
  integer(ik), parameter, public :: DIAG_STRAIN = 5             !! strain energy [J/m]
  integer(ik), parameter, public :: DIAG_MOMENTUM_X = 6         !! momentum, x and (DIAG_MOMENTUM_X + 1) y
  integer(ik), parameter, public :: DIAG_MOMENTUM_Y = 7
  integer(ik), parameter, public :: DIAG_GRAVITY_WORK = 8       !! work of gravity [J/m]
  integer(ik), parameter, public :: DIAG_BODY_FORCE_WORK = 9    !! work of the body forces [J/m]
  integer(ik), parameter, public :: DIAG_MASS = 10              !! total mass [kg/m]
  integer(ik), parameter, public :: DIAG_MAX_SIGNAL = 11        !! max signal speed [m/s]
  integer(ik), parameter, public :: DIAG_WALL_CLAMPS = 12       !! particles clamped at walls during the last step
  integer(ik), parameter, public :: DIAG_FRICTION_WORK = 13     !! frictional work of contact [J/m]
  integer(ik), parameter, public :: DIAG_VISCOUS = 14           !! viscous dissipation [J/m]
  integer(ik), parameter, public :: DIAG_CG_ITERATIONS = 15     !! incompressible: CG iterations of the last solve
  integer(ik), parameter, public :: DIAG_CG_RESIDUAL = 16       !! ... its relative residual
  integer(ik), parameter, public :: DIAG_CG_TOTAL = 17          !! ... CG iterations of all steps
  integer(ik), parameter, public :: DIAG_CORRECTION_WORK = 18   !! work of gravity on the volume correction's moves
  integer(ik), parameter, public :: NDIAG = 18
  character(len=SLOT_NAME_LEN), parameter, public :: DIAG_NAMES(NDIAG) = [character(len=SLOT_NAME_LEN) :: &
    "t", "dt", "steps", "kinetic_energy", "strain_energy", "momentum_x", "momentum_y", "gravity_work", &
    "body_force_work", "mass", "max_signal_speed", "wall_clamps", "friction_work", "viscous_dissipation", &
    "cg_iterations", "cg_residual", "cg_iterations_total", "correction_work"]

  ! phase timers, s%timers [s]
  integer(ik), parameter, public :: TIMER_SHAPE = 1        !! shape functions (and strips)
  integer(ik), parameter, public :: TIMER_P2G = 2          !! particle to grid
  integer(ik), parameter, public :: TIMER_GRID = 3         !! grid update
  integer(ik), parameter, public :: TIMER_G2P = 4          !! grid to particle (and the MUSL remap)
  integer(ik), parameter, public :: TIMER_DEFORMATION = 5  !! F and domains
  integer(ik), parameter, public :: TIMER_STRESS = 6       !! stress
  integer(ik), parameter, public :: TIMER_PROJECTION = 7   !! projection (operator, strain increment, mean stress)
  integer(ik), parameter, public :: TIMER_PRESSURE = 8     !! pressure solve (incompressible water)
  integer(ik), parameter, public :: NTIMER = 8
  character(len=SLOT_NAME_LEN), parameter, public :: TIMER_NAMES(NTIMER) = [character(len=SLOT_NAME_LEN) :: &
    "shape", "p2g", "grid", "g2p", "deformation", "stress", "projection", "pressure_solve"]

  ! the full state's particle rows (cpdi_get_full_state): first row of each field, and its width
  integer(ik), parameter, public :: ROW_X = 1, ROW_V = 3, ROW_F = 5, ROW_L = 9, ROW_SIG = 13, ROW_R = 17, &
                                    ROW_BF = 21, ROW_VOL = 23, ROW_PSI = 24, ROW_JBAR = 25, ROW_AW = 26
  integer(ik), parameter, public :: NPSTATE = 27           !! rows per particle
  integer(ik), parameter, public :: NROWFIELD = 11
  character(len=SLOT_NAME_LEN), parameter, public :: ROW_NAMES(NROWFIELD) = [character(len=SLOT_NAME_LEN) :: &
    "x", "v", "F", "L", "sigma", "r", "body_force", "vol", "psi", "jbar", "water_accel"]
  integer(ik), parameter, public :: ROW_FIRST(NROWFIELD) = [ROW_X, ROW_V, ROW_F, ROW_L, ROW_SIG, ROW_R, ROW_BF, &
                                                            ROW_VOL, ROW_PSI, ROW_JBAR, ROW_AW]
  ! the full state's scalars: these, then diag(NDIAG), then timers(NTIMER)
  integer(ik), parameter, public :: SCAL_T = 1, SCAL_STEPS = 2, SCAL_SMAX = 3, SCAL_VISC_DT = 4, SCAL_DT_LAST = 5
  integer(ik), parameter, public :: NSCALAR = 5
  character(len=SLOT_NAME_LEN), parameter, public :: SCALAR_NAMES(NSCALAR) = [character(len=SLOT_NAME_LEN) :: &
    "t", "steps", "smax", "visc_dt", "dt_last"]
  integer(ik), parameter, public :: NSSTATE = NSCALAR + NDIAG + NTIMER   !! scalars of the full state

end module cpdi_slots
