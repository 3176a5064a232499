!> Every solver option in one table: name, kind, default, range, unit and a one-line help.
module cpdi_options
  !! The table OPTIONS is the single source of the solver's options (issue 39 item 1). The API
  !! sets an option by name through opt_set, which checks it against its row (kind, components,
  !! range) in one place; Python reads the table through cpdi_option_info at import and builds
  !! Simulation.set_options and the case schema's [solver] keys from it. A simulation's values
  !! live in an optset_t (sim_t%ov), initialised from the table's defaults; the core reads an
  !! option by name (opt_value, opt_code, opt_is), and sim_apply_options (cpdi_sim) copies the
  !! options older than the table into the typed fields the stages read (s%opt, s%inc).
  !!
  !! A new option is one row here plus the line of the core that reads it. Cross-option rules
  !! (a rule between two rows) are in opt_check, which the API runs before a step and the case
  !! loader runs on a scratch simulation.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT
  implicit none
  private

  integer(ik), parameter, public :: OPT_REAL = 1   !! a real number
  integer(ik), parameter, public :: OPT_INT = 2    !! a whole number
  integer(ik), parameter, public :: OPT_BOOL = 3   !! 0 (false) or 1 (true)
  integer(ik), parameter, public :: OPT_ENUM = 4   !! 0-based index into choices ('a|b|c')

  integer(ik), parameter, public :: CASE_NO = 0        !! not a [solver] key of a case file
  integer(ik), parameter, public :: CASE_DEFAULT = 1   !! a [solver] key; absent: the default
  integer(ik), parameter, public :: CASE_OPTIONAL = 2  !! a [solver] key without a default (dt: given means fixed)

  integer, parameter, public :: OPT_NAME_LEN = 32
  integer, parameter, public :: OPT_CHOICE_LEN = 64
  integer, parameter, public :: OPT_UNIT_LEN = 16
  integer, parameter, public :: OPT_HELP_LEN = 512

  real(wp), parameter :: INF = huge(1.0_wp)   !! an unbounded side of a range

  type, public :: optdef_t
    !! One row of the table.
    character(len=OPT_NAME_LEN) :: name      !! the option's name (the case file's [solver] key)
    integer(ik) :: kind                      !! OPT_REAL, OPT_INT, OPT_BOOL or OPT_ENUM
    integer(ik) :: ncomp                     !! components: 1, or 2 for a vector (gravity)
    real(wp) :: default                      !! every component's default (an enum: its index)
    real(wp) :: lo, hi                       !! range (+-INF: unbounded; enum and bool: implied)
    logical :: lo_open, hi_open              !! the bound itself is excluded
    integer(ik) :: in_case                   !! CASE_NO, CASE_DEFAULT or CASE_OPTIONAL
    character(len=OPT_CHOICE_LEN) :: choices !! an enum's value names, '|'-separated, in index order
    character(len=OPT_UNIT_LEN) :: unit      !! SI unit ('' : none)
    character(len=OPT_HELP_LEN) :: help      !! one line: what it does (the case schema's doc)
  end type optdef_t

  type(optdef_t), parameter, public :: OPTIONS(*) = [ &
    optdef_t("shape", OPT_ENUM, 1, 2.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "mpm|gimp|cpdi", "", "interpolation"), &
    optdef_t("update", OPT_ENUM, 1, 1.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "usl|musl", "", "update scheme"), &
    optdef_t("projection", OPT_ENUM, 1, 0.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "none|cell|nodal", "", "volumetric anti-locking projection of ln J increments and mean stress: "// &
             "none, cell (cell-wise constant) or nodal (bilinear, banded LAPACK solve)"), &
    optdef_t("projection_stabilization", OPT_REAL, 1, 0.0_wp, 0.0_wp, 1.0_wp, .false., .false., CASE_DEFAULT, &
             "", "", "beta: the projected volumetric fields keep beta of each particle's own value, giving "// &
             "sub-cell (hourglass) motions a stiffness beta K"), &
    optdef_t("kinematics", OPT_ENUM, 1, 0.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "log|small", "", "log: finite strain (Hencky); small: sym(F) - I"), &
    optdef_t("domain_scaling", OPT_BOOL, 1, 0.0_wp, 0.0_wp, 1.0_wp, .false., .false., CASE_DEFAULT, &
             "", "", "Homel et al. (2016) CPDI domain scaling"), &
    optdef_t("cfl", OPT_REAL, 1, 0.3_wp, 0.0_wp, 1.0_wp, .true., .false., CASE_DEFAULT, &
             "", "", "Courant number of the explicit step"), &
    optdef_t("fixed_dt", OPT_BOOL, 1, 0.0_wp, 0.0_wp, 1.0_wp, .false., .false., CASE_NO, &
             "", "", "use dt instead of the CFL step (a case sets it by giving dt)"), &
    optdef_t("dt", OPT_REAL, 1, 0.0_wp, 0.0_wp, INF, .false., .false., CASE_OPTIONAL, &
             "", "s", "fixed time step (overrides cfl; refused if above the stable limit)"), &
    optdef_t("gravity", OPT_REAL, 2, 0.0_wp, -INF, INF, .false., .false., CASE_DEFAULT, &
             "", "m/s^2", "gravitational acceleration"), &
    optdef_t("damping", OPT_REAL, 1, 0.0_wp, 0.0_wp, 1.0_wp, .false., .true., CASE_DEFAULT, &
             "", "", "Cundall local damping coefficient (0 = none)"), &
    optdef_t("flip", OPT_REAL, 1, 1.0_wp, 0.0_wp, 1.0_wp, .false., .false., CASE_DEFAULT, &
             "", "", "FLIP fraction of the particle velocity update (1 = FLIP, 0 = PIC)"), &
    optdef_t("lcrit", OPT_REAL, 1, 0.49999_wp, 0.0_wp, 1.0_wp, .true., .false., CASE_NO, &
             "", "", "domain-scaling limit as a fraction of the cell size"), &
    optdef_t("fluid", OPT_ENUM, 1, 0.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "weakly_compressible|incompressible", "", "water model: weakly_compressible (the paper's "// &
             "explicit model, p from K ln J; time step from the speed of sound) or incompressible (pressure "// &
             "projection on a staggered grid; time step from the flow; water-only cases for now)"), &
    optdef_t("transfer", OPT_ENUM, 1, 0.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "flip|apic", "", "particle-grid velocity transfer: flip (FLIP/PIC blend set by flip) or apic "// &
             "(affine PIC; incompressible only)"), &
    optdef_t("cg_tolerance", OPT_REAL, 1, 1.0e-8_wp, 0.0_wp, 1.0_wp, .true., .true., CASE_DEFAULT, &
             "", "", "incompressible: relative residual of the pressure solve"), &
    optdef_t("correction_tolerance", OPT_REAL, 1, 1.0e-4_wp, 0.0_wp, 1.0_wp, .true., .true., CASE_DEFAULT, &
             "", "", "incompressible, water alone: relative residual of the volume correction's solve (coupled "// &
             "runs use cg_tolerance)"), &
    optdef_t("cg_max_iterations", OPT_INT, 1, 0.0_wp, 0.0_wp, 1.0e9_wp, .false., .true., CASE_DEFAULT, &
             "", "", "incompressible: CG iteration limit (0: 4 sqrt(cells) + 200)"), &
    optdef_t("volume_correction", OPT_REAL, 1, 0.5_wp, 0.0_wp, 2.0_wp, .false., .false., CASE_DEFAULT, &
             "", "", "incompressible: an over-filled cell gets div v = beta (fill - 1) / dt"), &
    optdef_t("pressure_precond", OPT_ENUM, 1, 0.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "mic0|multigrid", "", "incompressible: preconditioner of the pressure CG, mic0 (incomplete "// &
             "Cholesky; iterations grow like sqrt(cells)) or multigrid (a geometric multigrid V-cycle; "// &
             "iterations about constant)"), &
    optdef_t("solid_substeps", OPT_ENUM, 1, 0.0_wp, 0.0_wp, 0.0_wp, .false., .false., CASE_DEFAULT, &
             "off|explicit|implicit|auto", "", "incompressible water with deformable solids: auto (the "// &
             "coupling chooses by what the solids are: implicit, or explicit for a solid held by a prescribed "// &
             "rigid body), off (the coupled step is the solid's acoustic step), explicit (the solids' explicit "// &
             "steps subcycled inside the water's step) or implicit (explicit with the solids' volumetric "// &
             "stress implicit in the projection); docs/fsi_incompressible.md"), &
    optdef_t("theta_min", OPT_REAL, 1, 0.1_wp, 0.0_wp, 1.0_wp, .true., .false., CASE_DEFAULT, &
             "", "", "incompressible: closest the free surface may sit to a water cell's centre, in cells "// &
             "(the ghost-fluid pressure condition's 1/theta)") &
    ]
  integer(ik), parameter, public :: NOPT = size(OPTIONS)

  type, public :: optset_t
    !! One simulation's option values: v(1:ncomp, i) for row i of OPTIONS.
    real(wp) :: v(2, NOPT) = spread(OPTIONS%default, 1, 2)
  end type optset_t

  public :: opt_index, opt_set, opt_value, opt_code, opt_is, opt_check, opt_nchoices, opt_choice

contains

  pure integer(ik) function opt_index(name)
    !! Row of the option called name (0: none).
    character(len=*), intent(in) :: name
    integer(ik) :: i
    opt_index = 0
    do i = 1, NOPT
      if (trim(OPTIONS(i)%name) == trim(name)) then
        opt_index = i
        return
      end if
    end do
  end function opt_index

  pure integer(ik) function opt_nchoices(i)
    !! Values of enum row i (its '|'-separated names).
    integer(ik), intent(in) :: i
    integer :: k
    opt_nchoices = 1
    do k = 1, len_trim(OPTIONS(i)%choices)
      if (OPTIONS(i)%choices(k:k) == '|') opt_nchoices = opt_nchoices + 1
    end do
  end function opt_nchoices

  pure function opt_choice(i, code) result(word)
    !! Name of value code (0-based) of enum row i ('' if out of range).
    integer(ik), intent(in) :: i, code
    character(len=OPT_CHOICE_LEN) :: word
    integer :: k, first, n
    word = ''
    n = 0
    first = 1
    do k = 1, len_trim(OPTIONS(i)%choices) + 1
      if (k > len_trim(OPTIONS(i)%choices)) then
        if (n == code) word = OPTIONS(i)%choices(first:k - 1)
        return
      end if
      if (OPTIONS(i)%choices(k:k) == '|') then
        if (n == code) then
          word = OPTIONS(i)%choices(first:k - 1)
          return
        end if
        n = n + 1
        first = k + 1
      end if
    end do
  end function opt_choice

  pure function opt_value(os, name) result(x)
    !! First component of the option called name (NaN-free: a name not in the table is a
    !! programming error and gives huge, which the first use exposes).
    type(optset_t), intent(in) :: os
    character(len=*), intent(in) :: name
    real(wp) :: x
    integer(ik) :: i
    i = opt_index(name)
    x = huge(1.0_wp)
    if (i > 0) x = os%v(1, i)
  end function opt_value

  pure integer(ik) function opt_code(os, name)
    !! A whole-number, flag or enum option's value (an enum: its 0-based index).
    type(optset_t), intent(in) :: os
    character(len=*), intent(in) :: name
    opt_code = nint(opt_value(os, name), ik)
  end function opt_code

  pure logical function opt_is(os, name, word)
    !! Whether enum option name has the value called word.
    type(optset_t), intent(in) :: os
    character(len=*), intent(in) :: name, word
    integer(ik) :: i
    i = opt_index(name)
    opt_is = .false.
    if (i > 0) opt_is = trim(opt_choice(i, nint(os%v(1, i), ik))) == trim(word)
  end function opt_is

  function num(x) result(text)
    !! A number as short text: 0.3, 1e-08, 2.
    real(wp), intent(in) :: x
    character(len=32) :: text
    write (text, '(g0.12)') x
    text = adjustl(text)
    if (index(text, 'E') == 0 .and. index(text, '.') > 0) then
      do while (len_trim(text) > 1 .and. text(len_trim(text):len_trim(text)) == '0')
        text(len_trim(text):len_trim(text)) = ' '
      end do
      if (text(len_trim(text):len_trim(text)) == '.') text(len_trim(text):len_trim(text)) = ' '
    end if
  end function num

  function range_text(d) result(text)
    !! The range of a row, e.g. '(0, 1]'.
    type(optdef_t), intent(in) :: d
    character(len=80) :: text
    character(len=1) :: a, b
    a = merge('(', '[', d%lo_open)
    b = merge(')', ']', d%hi_open)
    if (d%hi >= INF) then
      text = a//trim(num(d%lo))//', inf)'
    else if (d%lo <= -INF) then
      text = '(-inf, '//trim(num(d%hi))//b
    else
      text = a//trim(num(d%lo))//', '//trim(num(d%hi))//b
    end if
  end function range_text

  subroutine opt_set(os, name, values, st)
    !! os's option name = values (1 or 2 components), checked against its row of the table:
    !! finite, an enum's index or a flag's 0/1, a whole number, inside the range. On error os
    !! is unchanged and st names the option and the allowed values.
    type(optset_t), intent(inout) :: os
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: values(:)
    type(status_t), intent(inout) :: st
    integer(ik) :: i, k, nc
    character(len=400) :: buf
    character(len=12) :: word
    type(optdef_t) :: d
    i = opt_index(name)
    if (i == 0) then
      buf = ''
      do k = 1, NOPT
        buf = trim(buf)//', '//trim(OPTIONS(k)%name)
      end do
      call st%set(CPDI_ERR_INPUT, 'unknown solver option '''//trim(name)//'''; use one of: '//trim(buf(3:)))
      return
    end if
    d = OPTIONS(i)
    if (size(values) /= d%ncomp) then
      write (buf, '(a,a,i0,a,i0)') trim(d%name), ' takes ', d%ncomp, ' value(s), got ', size(values)
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    if (.not. all(abs(values) <= huge(1.0_wp))) then
      call st%set(CPDI_ERR_INPUT, trim(d%name)//' contains NaN or Inf; give finite values')
      return
    end if
    do k = 1, d%ncomp
      select case (d%kind)
      case (OPT_ENUM)
        nc = opt_nchoices(i)
        if (values(k) /= aint(values(k)) .or. values(k) < 0.0_wp .or. values(k) > real(nc - 1, wp)) then
          buf = ''
          do nc = 0, opt_nchoices(i) - 1
            write (word, '(i0)') nc
            buf = trim(buf)//', '//trim(word)//' ('//trim(opt_choice(i, nc))//')'
          end do
          call st%set(CPDI_ERR_INPUT, trim(d%name)//' must be one of '//trim(buf(3:))//', got '// &
                      trim(num(values(k))))
          return
        end if
      case (OPT_BOOL)
        if (values(k) /= 0.0_wp .and. values(k) /= 1.0_wp) then
          call st%set(CPDI_ERR_INPUT, trim(d%name)//' is a flag: 0 or 1, got '//trim(num(values(k))))
          return
        end if
      case default
        if (d%kind == OPT_INT .and. values(k) /= aint(values(k))) then
          call st%set(CPDI_ERR_INPUT, trim(d%name)//' must be a whole number, got '//trim(num(values(k))))
          return
        end if
        if (values(k) < d%lo .or. values(k) > d%hi .or. (d%lo_open .and. values(k) == d%lo) &
            .or. (d%hi_open .and. values(k) == d%hi)) then
          call st%set(CPDI_ERR_INPUT, trim(d%name)//' = '//trim(num(values(k)))//' must lie in '// &
                      trim(range_text(d))//' ('//trim(d%help)//')')
          return
        end if
      end select
    end do
    os%v(1:d%ncomp, i) = values
  end subroutine opt_set

  subroutine opt_check(os, st)
    !! The rules between options (each row alone is checked by opt_set).
    type(optset_t), intent(in) :: os
    type(status_t), intent(inout) :: st
    if (opt_code(os, 'fixed_dt') == 1 .and. .not. (opt_value(os, 'dt') > 0.0_wp)) then
      call st%set(CPDI_ERR_INPUT, 'a fixed time step dt must be positive (s)')
    else if (opt_is(os, 'transfer', 'apic') .and. .not. opt_is(os, 'fluid', 'incompressible')) then
      call st%set(CPDI_ERR_INPUT, "transfer = 'apic' is available with fluid = 'incompressible' only; "// &
                  "use transfer = 'flip' (with flip) for the weakly compressible model")
    end if
  end subroutine opt_check

end module cpdi_options
