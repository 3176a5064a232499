!> Incompressible water: the semi-implicit (Chorin) step on the staggered grid.
module cpdi_incompressible
  !! The second water model (`fluid = incompressible`). One step, for a body of water:
  !!
  !! 1. particle-to-grid transfer of mass and momentum to the u and v face lattices, with
  !!    the run's interpolation (linear, uGIMP or CPDI weights evaluated on the node lattice
  !!    shifted by h/2), PIC/FLIP or APIC (Jiang et al. 2015: m v_i = sum w m (v_p + C_p (x_i - x_p)));
  !! 2. explicit forces on the faces: gravity and body forces, viscosity (5-point Laplacian);
  !! 3. the pressure projection (cpdi_pressure): cells with water, their fill fraction and a
  !!    ghost-fluid free surface, MIC(0)-CG, u <- u - dt/rho grad p, extrapolation to the faces
  !!    next to the water;
  !! 4. grid-to-particle transfer (FLIP/PIC blend, or APIC's velocity and affine matrix
  !!    C_p = sum_i v_i grad w_ip^T, exact for affine fields with these weights), advection
  !!    with the grid velocity, and the particle pressure from the cell pressure.
  !!
  !! Water particles keep F = I and their initial volume, and so their CPDI domains: the
  !! water is incompressible, and the grid velocity is divergence-free to the solver's
  !! tolerance. Axis-aligned rectangles then stay rectangles, whose CPDI1 weights are products of
  !! 1D factors: water-only CPDI runs evaluate them inside P2G and G2P instead of storing them
  !! (separable_rows, sep_axis). The time step follows the flow (cpdi_step: h / (max|v| + sqrt(|g| h)) and the
  !! viscous limit), not the speed of sound.
  use, intrinsic :: iso_fortran_env, only: int64
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT, CPDI_ERR_ALLOC, CPDI_ERR_OUTSIDE, CPDI_ERR_DOMAIN, CPDI_ERR_SOLVE, &
                         CPDI_ERR_NAN
  use cpdi_grid, only: grid_t, hold_on_walls, grid_box, grid_apply_walls, WALL_OPEN, GRID_PAD
  use cpdi_particles, only: particles_t
  use cpdi_shape, only: shape_t, shape_alloc, shape_compute, SHAPE_FAIL_INVERTED, SHAPE_CPDI
  use cpdi_schedule, only: NCHUNK, chunk_range, strips_t, strips_alloc, strips_build, strip_start, block_next, &
                           blocks_t, blocks_region, blocks_enter
  use cpdi_materials, only: material_t, MAT_FLUID, MAT_RIGID, MAT_RIGID_BODY
  use cpdi_rigid_body, only: rbody_t, rb_prepare, rb_assemble, rb_impulse
  use cpdi_options, only: opt_value
  use cpdi_slots, only: DIAG_KINETIC, DIAG_STRAIN, DIAG_MOMENTUM_X, DIAG_MOMENTUM_Y, DIAG_GRAVITY_WORK, &
                        DIAG_BODY_FORCE_WORK, DIAG_WALL_CLAMPS, DIAG_CG_ITERATIONS, DIAG_CG_RESIDUAL, DIAG_CG_TOTAL, &
                        DIAG_CORRECTION_WORK, NDIAG, TIMER_SHAPE, TIMER_P2G, TIMER_GRID, TIMER_G2P, TIMER_PRESSURE
  use cpdi_pressure, only: mac_t, mac_alloc, mac_mark_outside, mac_walls, mac_assemble, mac_solve, mac_project, &
                           mac_extrapolate, mac_constrain, mac_ghost_pressure, mac_level_set, LVL_WATER, CELL_FLUID, CELL_AIR, &
                           CELL_SOLID
  use cpdi_coupling, only: cpl_fractions, cpl_classify, cpl_close, cpl_assemble, cpl_impulse
  implicit none
  private

  integer(ik), parameter, public :: FLUID_WEAKLY_COMPRESSIBLE = 0
  integer(ik), parameter, public :: FLUID_INCOMPRESSIBLE = 1
  integer(ik), parameter, public :: TRANSFER_FLIP = 0   !! FLIP/PIC blend (the run's flip fraction)
  integer(ik), parameter, public :: TRANSFER_APIC = 1   !! affine particle-in-cell
  integer(ik), parameter :: EXTRAPOLATION_LAYERS = 2
  integer(ik), parameter :: SEPARATION_SWEEPS = 8   !! solves at most per step that let water leave a free body
  integer(ik), parameter, public :: COUPLING_MIXTURE = 0  !! solids and water one continuum on the faces
  integer(ik), parameter, public :: COUPLING_BATTY = 1    !! water-only pressure cells, solid boundary fluxes
  integer(ik), parameter, public :: SUBSTEPS_OFF = 0       !! solid_substeps = "off": the solids' acoustic step
  integer(ik), parameter, public :: SUBSTEPS_EXPLICIT = 1  !! "explicit": the solids' explicit steps subcycled
  integer(ik), parameter, public :: SUBSTEPS_IMPLICIT = 2  !! "implicit": explicit, the solids' volumetric
                                                           !! stress implicit in the projection
  integer(ik), parameter, public :: SUBSTEPS_AUTO = 3      !! "auto": the coupling chooses by what the solids
                                                           !! are (cpdi_step prepare_solids)

  type, public :: incomp_t
    !! Settings and work storage of the incompressible water model.
    integer(ik) :: transfer = TRANSFER_FLIP
    real(wp) :: beta = 0.5_wp          !! volume correction: target div v = beta (fill - 1) / dt
    real(wp) :: tol = 1.0e-8_wp        !! CG relative residual
    integer(ik) :: maxit = 0           !! CG iteration limit (0: 4 sqrt(cells) + 200)
    real(wp) :: rho = 0.0_wp           !! water density [kg/m^3]
    real(wp) :: visc = 0.0_wp          !! water viscosity [Pa s]
    type(grid_t) :: gu, gv             !! u and v face lattices (geometry only)
    type(shape_t) :: shu, shv          !! weights of every particle on them (not filled when sep)
    logical :: sep = .false.           !! this step's weights are the separable CPDI1 rectangles (sep_axis),
                                       !! evaluated where P2G and G2P need them; only shu%row, shv%row are set
    type(strips_t) :: sp               !! particles in strips of face rows: P2G to the faces (cpdi_schedule)
    integer(ik), allocatable :: prow(:) !! lowest face or cell row a particle's P2G touches (0-based)
    type(mac_t) :: mc                  !! staggered fields and the pressure system
    real(wp) :: red(8, NCHUNK) = 0.0_wp
    ! Solids coupled to the water (docs/fsi_incompressible.md): a single continuum on the faces.
    logical :: coupled = .false.       !! solid particles take part (cpdi_fsi drives the step)
    logical, allocatable :: solid(:)   !! per material: a deformable solid (its mass joins the faces)
    logical, allocatable :: rigid(:)   !! per material: a rigid body (its cells bound the water)
    logical, allocatable :: free(:)    !! per material: a free rigid body (cpdi_rigid_body)
    type(rbody_t) :: rb                !! the free rigid bodies
    real(wp), allocatable :: rvel(:, :) !! per material: a rigid body's prescribed velocity
    real(wp), allocatable :: usm(:), vsm(:)   !! solid face masses
    real(wp), allocatable :: uvw(:), vvw(:)   !! water face volumes
    real(wp), allocatable :: uvs(:), vvs(:)   !! solid face volumes
    real(wp), allocatable :: us(:), vs(:)     !! solid face velocities before projection; after it, their change
    real(wp), allocatable :: umx(:), vmx(:)   !! mixture face velocities before projection
    real(wp), allocatable :: nwx(:), nwy(:)   !! nodal weights of the face-to-node return
    real(wp), allocatable :: fillw(:)         !! cell fill of the water alone (the volume correction's target)
    real(wp) :: dt_corr = 0.0_wp       !! coupled: the water's own step, the volume correction's time scale
    real(wp) :: smax_w = 0.0_wp        !! coupled: the water's signal speed of the last step
    real(wp) :: fsolid(2) = 0.0_wp     !! force of the water on the solids in the last step [N/m] (cpdi_fsi)
    integer(ik) :: coupling = COUPLING_MIXTURE   !! how solids join the projection (cpdi_coupling for batty)
    real(wp), allocatable :: wu(:), wv(:)     !! batty: solid fractions of the faces
    real(wp), allocatable :: phi(:)           !! batty: solid fraction of the cells (from the faces)
    real(wp), allocatable :: sfill(:)         !! batty: the solid's cell fill (spread like fillw)
    real(wp), allocatable :: iu(:), iv(:)     !! batty: the pressure's impulse on the solid faces
    real(wp), allocatable :: svol(:)          !! batty: the solids' nodal volume (walls' volume constraint)
    real(wp) :: vfull = 0.0_wp                !! batty: fullness h^2 (cpdi_fsi; grid_apply_walls)
    ! Deformable solids subcycled inside the water's step (cpdi_step subcycle_solids, cpdi_fsi)
    integer(ik) :: substeps = 0               !! option solid_substeps: 0 off (the solids' acoustic step), 1
                                              !! explicit, 2 implicit, 3 auto (the coupling chooses)
    integer(ik) :: submode = 0                !! the mode this run steps with (cpdi_step prepare_solids): 0 off,
                                              !! 1 explicit, 2 implicit
    ! solid_substeps = "implicit" (cpdi_fsi solid_compliance): per cell, sum of w V_p / (h^2 K_p) over the
    ! solid particles (cmp) and of w V_p p_p / (h^2 K_p) (cmpp), p_p their in-plane mean pressure at t^n
    real(wp), allocatable :: cmp(:), cmpp(:)
    logical :: subcycled = .false.            !! this run's solids are subcycled (cpdi_step prepare_solids)
  end type incomp_t

  public :: incomp_prepare, incomp_step, incomp_transfer_cycle, incomp_pressure_at, incomp_fill_weights

contains

  subroutine incomp_prepare(ic, g, p, mats, shape_kind, damping, st, body)
    !! Check that the run is one the projection handles (water only, one density, no
    !! damping), size the work storage and put the water at F = I, V = V0. body: per particle,
    !! its body index (free rigid bodies are numbered by it; without it, by material).
    type(incomp_t), intent(inout) :: ic
    type(grid_t), intent(in) :: g
    type(particles_t), intent(inout) :: p
    type(material_t), intent(in) :: mats(:)
    integer(ik), intent(in) :: shape_kind
    real(wp), intent(in) :: damping
    type(status_t), intent(inout) :: st
    integer(ik), intent(in), optional :: body(:)
    integer(ik) :: m, first, lo(2), hi(2)
    character(len=300) :: buf
    logical :: used(size(mats)), realloc

    used = .false.
    used(p%mat) = .true.
    first = 0
    if (allocated(ic%solid)) deallocate (ic%solid, ic%rigid, ic%rvel, ic%free)
    allocate (ic%solid(size(mats)), ic%rigid(size(mats)), ic%rvel(2, size(mats)), ic%free(size(mats)))
    ic%rigid = mats%model == MAT_RIGID
    ic%free = mats%model == MAT_RIGID_BODY
    ic%solid = mats%model /= MAT_FLUID .and. .not. ic%rigid .and. .not. ic%free
    do m = 1, size(mats)
      ic%rvel(:, m) = mats(m)%vel
    end do
    ic%coupled = any((ic%solid .or. ic%rigid .or. ic%free) .and. used)
    ! the coupling is chosen by what the solids are: one continuum on the faces with deformable and
    ! prescribed solids, the boundary flux with free rigid bodies
    ic%coupling = COUPLING_MIXTURE
    if (any(ic%free .and. used)) then
      ! free rigid bodies couple through the boundary-flux operator (cpdi_rigid_body); a deformable
      ! solid beside them would need its own share of every face's solid fraction
      if (any(ic%solid .and. used)) then
        call st%set(CPDI_ERR_INPUT, 'a rigid_body material cannot yet share a run with a deformable solid '// &
                    '(hencky, neo_hookean); make the solids rigid_body, or run them in separate cases')
        return
      end if
      ic%coupling = COUPLING_BATTY
    end if
    do m = 1, size(mats)
      if (.not. used(m)) cycle
      if (mats(m)%model /= MAT_FLUID) cycle
      if (first == 0) then
        first = m
      else if (mats(m)%rho0 /= mats(first)%rho0 .or. mats(m)%visc /= mats(first)%visc) then
        write (buf, '(a,i0,a,i0,a)') 'fluid materials ', first, ' and ', m, ' differ in density or viscosity: '// &
          'fluid = "incompressible" solves for one water; give them the same values'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
    end do
    if (first == 0) then
      call st%set(CPDI_ERR_INPUT, 'fluid = "incompressible" needs a newtonian_fluid material (the water); '// &
                  'add one, or use fluid = "weakly_compressible"')
      return
    end if
    if (damping /= 0.0_wp) then
      call st%set(CPDI_ERR_INPUT, 'damping is not available with fluid = "incompressible" (water at rest is '// &
                  'exactly at rest without it); set [solver] damping = 0')
      return
    end if
    ic%rho = mats(first)%rho0
    ic%visc = mats(first)%visc
    ic%gu = lattice(g, [0.0_wp, 0.5_wp])
    ic%gv = lattice(g, [0.5_wp, 0.0_wp])
    realloc = .not. allocated(ic%shu%idx)
    if (.not. realloc) realloc = ic%shu%kind /= shape_kind .or. size(ic%shu%w, 2) /= p%n
    if (.not. realloc) realloc = size(ic%sp%start) /= g%nn(2) + 2
    if (realloc) then
      call shape_alloc(ic%shu, shape_kind, p%n, st)
      if (st%ok()) call shape_alloc(ic%shv, shape_kind, p%n, st)
      if (st%ok()) call strips_alloc(ic%sp, p%n, g%nn(2), st)
      if (.not. st%ok()) return
      if (allocated(ic%prow)) deallocate (ic%prow)
      allocate (ic%prow(p%n), stat=m)
      if (m /= 0) then
        call st%set(CPDI_ERR_ALLOC, 'could not allocate the particle ordering; use fewer particles')
        return
      end if
    end if
    lo = GRID_PAD + 1
    hi = GRID_PAD + g%ncell
    realloc = .not. allocated(ic%mc%cell)
    if (.not. realloc) realloc = any(ic%mc%nn /= g%nn)
    if (realloc) then
      call mac_alloc(ic%mc, g%nn, lo, hi, g%h, st)
      if (.not. st%ok()) return
    end if
    call mac_mark_outside(ic%mc, g%walls /= WALL_OPEN)
    if (ic%maxit == 0) ic%maxit = int(4.0_wp*sqrt(real(product(g%ncell), wp))) + 200
    if (ic%coupled) then
      realloc = .not. allocated(ic%usm)
      if (.not. realloc) realloc = size(ic%usm) /= g%nnodes
      if (realloc) then
        if (allocated(ic%usm)) deallocate (ic%usm, ic%vsm, ic%uvw, ic%vvw, ic%uvs, ic%vvs, ic%us, ic%vs, ic%umx, &
                                           ic%vmx, ic%nwx, ic%nwy, ic%fillw, ic%wu, ic%wv, ic%phi, ic%iu, ic%iv, &
                                           ic%sfill, ic%svol, ic%cmp, ic%cmpp)
        allocate (ic%usm(g%nnodes), ic%vsm(g%nnodes), ic%uvw(g%nnodes), ic%vvw(g%nnodes), ic%uvs(g%nnodes), &
                  ic%vvs(g%nnodes), ic%us(g%nnodes), ic%vs(g%nnodes), ic%umx(g%nnodes), ic%vmx(g%nnodes), &
                  ic%nwx(g%nnodes), ic%nwy(g%nnodes), ic%fillw(size(ic%mc%fill)), ic%wu(g%nnodes), ic%wv(g%nnodes), &
                  ic%phi(size(ic%mc%fill)), ic%iu(g%nnodes), ic%iv(g%nnodes), ic%sfill(size(ic%mc%fill)), &
                  ic%svol(g%nnodes), ic%cmp(size(ic%mc%fill)), ic%cmpp(size(ic%mc%fill)), stat=m)
        if (m /= 0) then
          call st%set(CPDI_ERR_ALLOC, 'could not allocate the coupling storage; use a larger cell size')
          return
        end if
        ! every entry defined from the start, as mac_alloc does for the pressure grid: memory
        ! fresh from malloc holds what the process freed before (an unwritten sfill entry made a
        ! run's result depend on the runs before it in the same process; cpl_classify)
        ic%usm = 0.0_wp; ic%vsm = 0.0_wp; ic%uvw = 0.0_wp; ic%vvw = 0.0_wp; ic%uvs = 0.0_wp; ic%vvs = 0.0_wp
        ic%us = 0.0_wp; ic%vs = 0.0_wp; ic%umx = 0.0_wp; ic%vmx = 0.0_wp; ic%nwx = 0.0_wp; ic%nwy = 0.0_wp
        ic%fillw = 0.0_wp; ic%wu = 0.0_wp; ic%wv = 0.0_wp; ic%phi = 0.0_wp; ic%iu = 0.0_wp; ic%iv = 0.0_wp
        ic%sfill = 0.0_wp; ic%svol = 0.0_wp; ic%cmp = 0.0_wp; ic%cmpp = 0.0_wp
      end if
      call prepare_bodies()
      if (.not. st%ok()) return
      do m = 1, p%n   ! the water only: the solids keep their deformation
        if (ic%solid(p%mat(m)) .or. ic%rigid(p%mat(m)) .or. ic%free(p%mat(m))) cycle
        p%F(:, m) = [1.0_wp, 0.0_wp, 0.0_wp, 1.0_wp]
        p%vol(m) = p%vol0(m)
        p%jbar(m) = 1.0_wp
        p%r(:, m) = p%r0(:, m)
        p%psi(m) = 0.0_wp
      end do
      return
    end if
    p%F(1, :) = 1.0_wp
    p%F(2, :) = 0.0_wp
    p%F(3, :) = 0.0_wp
    p%F(4, :) = 1.0_wp
    p%vol = p%vol0
    p%jbar = 1.0_wp
    p%r = p%r0
    p%psi = 0.0_wp
  contains
    subroutine prepare_bodies()
      !! The free rigid bodies and the pressure system's low-rank storage for them.
      integer(ik) :: ierr
      if (present(body)) then
        call rb_prepare(ic%rb, ic%free, body, p, mats%friction, g%nnodes, st)
      else
        call rb_prepare(ic%rb, ic%free, p%mat, p, mats%friction, g%nnodes, st)
      end if
      if (.not. st%ok()) return
      ! the walls are the only contact a free body has: two bodies, or a body and a prescribed one,
      ! would pass through each other
      if (ic%rb%n > 1) then
        call st%set(CPDI_ERR_INPUT, 'more than one free rigid body (rigid_body): bodies do not yet touch '// &
                    'each other and would pass through one another; use one rigid_body body per run')
        return
      end if
      if (ic%rb%n > 0 .and. any(ic%rigid .and. used)) then
        call st%set(CPDI_ERR_INPUT, 'a free rigid body (rigid_body) with a prescribed one (rigid): they do not '// &
                    'yet touch each other and would pass through one another; use one of the two per run')
        return
      end if
      ic%mc%nlr = 0
      if (allocated(ic%mc%lrc)) deallocate (ic%mc%lrc, ic%mc%lrb, ic%mc%lrj, ic%mc%lrd)
      allocate (ic%mc%lrc(g%nnodes*ic%rb%n), ic%mc%lrb(g%nnodes*ic%rb%n), ic%mc%lrj(3, g%nnodes*ic%rb%n), &
                ic%mc%lrd(3, ic%rb%n), stat=ierr)
      if (ierr /= 0) call st%set(CPDI_ERR_ALLOC, 'could not allocate the rigid bodies'' pressure rows; '// &
                                 'use a larger cell size')
    end subroutine prepare_bodies
  end subroutine incomp_prepare

  pure function lattice(g, shift) result(gs)
    !! The node lattice of g shifted by shift*h (geometry only: no nodal fields).
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: shift(2)
    type(grid_t) :: gs
    gs%origin = g%origin
    gs%h = g%h
    gs%gorig = g%gorig + shift*g%h
    gs%ncell = g%ncell
    gs%nn = g%nn
    gs%nnodes = g%nnodes
    gs%walls = g%walls
    gs%wall_node = g%wall_node
  end function lattice

  subroutine weights(ic, p, steps, st)
    !! Weights of every particle on both face lattices; a clear error if a particle left them.
    type(incomp_t), intent(inout) :: ic
    type(particles_t), intent(in) :: p
    integer(int64), intent(in) :: steps
    type(status_t), intent(inout) :: st
    integer(ik) :: bad, fail, pass
    character(len=300) :: buf
    call separable_rows(ic, p, bad)
    if (ic%sep) then
      if (bad == 0) return
      write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', steps + 1, ': particle ', bad, ' at (', p%x(:, bad), &
        ') has left the grid; enlarge [grid] size or close the wall'
      call st%set(CPDI_ERR_OUTSIDE, trim(buf))
      return
    end if
    do pass = 1, 2
      ! shape_compute is orphaned worksharing over fixed particle blocks: the same weights at
      ! any thread count
      call blocks_region()
      !$omp parallel default(shared)
      call blocks_enter()
      if (pass == 1) call shape_compute(ic%gu, p, ic%shu, bad, fail, st)
      if (pass == 2) call shape_compute(ic%gv, p, ic%shv, bad, fail, st)
      !$omp end parallel
      if (.not. st%ok()) return
      if (bad == 0) cycle
      if (fail == SHAPE_FAIL_INVERTED) then
        write (buf, '(a,i0,a,i0,a)') 'step ', steps + 1, ': CPDI domain of particle ', bad, &
          ' is inverted; check the particle domains'
        call st%set(CPDI_ERR_DOMAIN, trim(buf))
      else
        write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', steps + 1, ': particle ', bad, ' at (', p%x(:, bad), &
          ') has left the grid; enlarge [grid] size or close the wall'
        call st%set(CPDI_ERR_OUTSIDE, trim(buf))
      end if
      return
    end do
  end subroutine weights

  subroutine separable_rows(ic, p, bad)
    !! Decides ic%sep: CPDI weights, water alone (not coupled), and every particle's domain an
    !! axis-aligned rectangle (r1 = (a, 0), r2 = (0, b), a, b > 0) whose corners lie in a 2 x 2
    !! block of cells on both face lattices. Then S_ip = 1/4 sum_c N_i(x_c) is the tensor product
    !! of sep_axis's 1D factors, and so is CPDI1's gradient: the weights are evaluated where the
    !! transfers use them (p2g_particle, g2p_faces) and nothing is stored but each particle's
    !! first node row per lattice (for the strips). bad: with sep, the lowest particle that left
    !! a lattice (the u lattice's first, as shape_compute's passes report), else 0.
    type(incomp_t), intent(inout) :: ic
    type(particles_t), intent(in) :: p
    integer(ik), intent(out) :: bad
    integer(ik) :: ip, nwide, badu, badv, fu, fv, f1, f2, i0, j0
    real(wp) :: rhu, rhv
    bad = 0
    ic%sep = ic%shu%kind == SHAPE_CPDI .and. .not. ic%coupled
    if (.not. ic%sep) return
    rhu = 1.0_wp/ic%gu%h
    rhv = 1.0_wp/ic%gv%h
    nwide = 0
    badu = huge(badu)
    badv = huge(badv)
    !$omp parallel do schedule(static) default(shared) private(ip, fu, fv, f1, f2, i0, j0) &
    !$omp reduction(+:nwide) reduction(min:badu, badv)
    do ip = 1, p%n
      if (.not. (p%r(2, ip) == 0.0_wp .and. p%r(3, ip) == 0.0_wp .and. p%r(1, ip) > 0.0_wp .and. &
                 p%r(4, ip) > 0.0_wp)) then
        nwide = nwide + 1
        cycle
      end if
      call sep_check(p%x(1, ip), p%r(1, ip), ic%gu%gorig(1), rhu, ic%gu%nn(1), i0, f1)
      call sep_check(p%x(2, ip), p%r(4, ip), ic%gu%gorig(2), rhu, ic%gu%nn(2), j0, f2)
      ic%shu%row(ip) = j0
      fu = max(f1, f2)
      call sep_check(p%x(1, ip), p%r(1, ip), ic%gv%gorig(1), rhv, ic%gv%nn(1), i0, f1)
      call sep_check(p%x(2, ip), p%r(4, ip), ic%gv%gorig(2), rhv, ic%gv%nn(2), j0, f2)
      ic%shv%row(ip) = j0
      fv = max(f1, f2)
      if (fu == 2 .or. fv == 2) nwide = nwide + 1
      if (fu == 1) badu = min(badu, ip)
      if (fv == 1) badv = min(badv, ip)
    end do
    !$omp end parallel do
    ic%sep = nwide == 0
    if (.not. ic%sep) return
    ic%shu%span = 2
    ic%shv%span = 2
    if (badu < huge(badu)) then
      bad = badu
    else if (badv < huge(badv)) then
      bad = badv
    end if
  end subroutine separable_rows

  pure subroutine sep_check(x, a, o, rh, n, i0, f)
    !! sep_axis's first node i0 (0-based) and f: 0, 1 a corner outside the lattice, 2 the corners
    !! more than one cell apart (not separable in a 3 x 3 block).
    real(wp), intent(in) :: x, a, o, rh
    integer(ik), intent(in) :: n
    integer(ik), intent(out) :: i0, f
    real(wp) :: u1, u2
    u1 = (x - a - o)*rh
    u2 = (x + a - o)*rh
    f = 0
    i0 = 0
    if (.not. (u1 >= 0.0_wp .and. u2 < real(n - 1, wp))) then
      f = 1
    else
      i0 = int(u1, ik)
      if (int(u2, ik) - i0 > 1) f = 2
    end if
  end subroutine sep_check

  pure subroutine sep_axis(x, a, o, rh, i0, s, d)
    !! One axis of an axis-aligned CPDI1 rectangle of centre x and half-width a on a lattice
    !! from o (1/h = rh): its three nodes from i0 (0-based), the weight factor
    !! s = (N(x - a) + N(x + a))/2 and the gradient factor d = (N(x + a) - N(x - a))/(2 a) there
    !! (N the 1D hat): w = s_x s_y, grad w = (d_x s_y, s_x d_y), the four corners' CPDI1 sums in
    !! product form. The corners' local coordinates are formed as shape_cpdi_batch forms them.
    !! Only for a rectangle sep_check accepted (inside the lattice, corners one cell apart at most).
    real(wp), intent(in) :: x, a, o, rh
    integer(ik), intent(out) :: i0
    real(wp), intent(out) :: s(3), d(3)
    real(wp) :: u1, u2, h11, h12, h21, h22, h23, ra
    u1 = (x - a - o)*rh
    u2 = (x + a - o)*rh
    i0 = int(u1, ik)
    u1 = u1 - real(i0, wp)   ! in [0, 1): the hats 1 - u1, u1, 0
    u2 = u2 - real(i0, wp)   ! in [0, 2)
    h11 = 1.0_wp - u1
    h12 = u1
    h21 = max(0.0_wp, 1.0_wp - u2)
    h22 = max(0.0_wp, 1.0_wp - abs(u2 - 1.0_wp))
    h23 = max(0.0_wp, u2 - 1.0_wp)
    ra = 0.5_wp/a
    s(1) = 0.5_wp*(h11 + h21)
    s(2) = 0.5_wp*(h12 + h22)
    s(3) = 0.5_wp*h23
    d(1) = (h21 - h11)*ra
    d(2) = (h22 - h12)*ra
    d(3) = h23*ra
  end subroutine sep_axis

  subroutine p2g_faces(ic, p, g, dt, gravity, apic)
    !! Face masses and momenta (u, v), the impulse of gravity and body forces (uo, vo),
    !! the cells holding water and their fill fraction. Threaded by strips of rows
    !! (cpdi_schedule): each particle's stencils on both face lattices and its cells lie within
    !! its strip and the next, so the strips of one colour scatter in parallel; every face and
    !! cell sums one even and one odd strip, each in particle order, at any thread count.
    type(incomp_t), intent(inout) :: ic
    type(particles_t), intent(in) :: p
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: dt, gravity(2)
    logical, intent(in) :: apic
    integer(ik) :: ip, k, i, j, n1, span, colour, b, m
    real(wp) :: av
    logical :: batty
    type(blocks_t) :: blk
    batty = ic%coupled .and. ic%coupling == COUPLING_BATTY
    associate (mc => ic%mc)
      n1 = mc%nn(1)
      !$omp parallel do schedule(static)   ! element-wise: the same bits at any thread count
      do k = 1, size(mc%um)
        mc%um(k) = 0.0_wp
        mc%vm(k) = 0.0_wp
        mc%u(k) = 0.0_wp
        mc%v(k) = 0.0_wp
        mc%uo(k) = 0.0_wp
        mc%vo(k) = 0.0_wp
        mc%fill(k) = 0.0_wp
        if (mc%cell(k) == CELL_FLUID) mc%cell(k) = CELL_AIR   ! walls stay
      end do
      !$omp end parallel do
      if (ic%coupled) call clear_coupled()
    end associate
    av = 1.0_wp/g%h**2
    span = 0
    call blocks_region()
    !$omp parallel default(shared) private(ip, colour, b, m, blk)
    call blocks_enter()
    !$omp do schedule(static) reduction(max:span)
    do ip = 1, p%n
      span = max(span, p2g_rows(ic, p, g, ip))
    end do
    !$omp end do
    call strips_build(ic%sp, ic%prow, span)
    do colour = 1, 2
      call strip_start(blk, ic%sp, colour)
      do while (block_next(blk, b))
        do m = ic%sp%start(b), ic%sp%start(b + 1) - 1
          call p2g_particle(ic, p, g, ic%sp%perm(m), dt, gravity, apic, batty, av)
        end do
      end do
      !$omp barrier
    end do
    !$omp end parallel
    associate (mc => ic%mc)
      ! a cell without a particle centre inside the water is still water: the particles'
      ! volume covers it (a pocket of p = 0 there would pull the water around it in)
      ! (batty coupling: cpl_classify, from the water's own fill)
      ! Water alone (levelset): the surface is mac_level_set's. A cell is water where the level set
      ! puts its centre inside the water; a cell holding a particle's centre but lying above the
      ! surface next to a water cell is air (its particles move with the extrapolated velocity of the
      ! water below, as a level set's particles outside the water do); one holding a particle's
      ! centre with no such neighbour (spray, a thin sheet) stays water, its surface at theta_min.
      mc%levelset = .not. ic%coupled
      if (mc%levelset) then
        call mac_level_set(mc)
        !$omp parallel do schedule(static) private(i, k)   ! each cell from lvl (read only): element-wise
        do j = mc%lo(2), mc%hi(2)
          do i = mc%lo(1), mc%hi(1)
            k = i + (j - 1)*n1
            if (mc%cell(k) == CELL_SOLID) cycle
            if (mc%lvl(k) < LVL_WATER) then
              mc%cell(k) = CELL_FLUID
            else if (mc%cell(k) == CELL_FLUID) then
              if (any(mc%lvl([k - 1, k + 1, k - n1, k + n1]) < LVL_WATER)) mc%cell(k) = CELL_AIR
            end if
          end do
        end do
        !$omp end parallel do
      else if (.not. batty) then
      do j = mc%lo(2), mc%hi(2)
        do i = mc%lo(1), mc%hi(1)
          k = i + (j - 1)*n1
          if (mc%fill(k) > 0.5_wp .and. mc%cell(k) /= CELL_SOLID) mc%cell(k) = CELL_FLUID
        end do
      end do
      end if
    end associate
    if (ic%coupled) call mark_rigid()
  contains
    subroutine clear_coupled()
      !! Coupling fields to zero; the last step's rigid cells back to air.
      n1 = ic%mc%nn(1)
      do j = ic%mc%lo(2), ic%mc%hi(2)
        do i = ic%mc%lo(1), ic%mc%hi(1)
          k = i + (j - 1)*n1
          if (ic%mc%cell(k) == CELL_SOLID) ic%mc%cell(k) = CELL_AIR
          ic%mc%rvx(k) = 0.0_wp
          ic%mc%rvy(k) = 0.0_wp
        end do
      end do
      ic%usm = 0.0_wp
      ic%vsm = 0.0_wp
      ic%uvw = 0.0_wp
      ic%vvw = 0.0_wp
      ic%uvs = 0.0_wp
      ic%vvs = 0.0_wp
      ic%mc%ua = 1.0_wp
      ic%mc%va = 1.0_wp
      ic%fillw = 0.0_wp
      if (ic%rb%n > 0) then
        ic%rb%uvb = 0.0_wp
        ic%rb%vvb = 0.0_wp
      end if
    end subroutine clear_coupled

    subroutine mark_rigid()
      !! Cells holding a rigid particle's centre bound the water with the body's velocity.
      real(wp) :: sx(2)
      do ip = 1, p%n
        if (.not. ic%rigid(p%mat(ip))) cycle
        sx = (p%x(:, ip) - g%gorig)/g%h
        i = int(sx(1)) + 1
        j = int(sx(2)) + 1
        if (i < ic%mc%lo(1) .or. i > ic%mc%hi(1) .or. j < ic%mc%lo(2) .or. j > ic%mc%hi(2)) cycle
        k = i + (j - 1)*n1
        ic%mc%cell(k) = CELL_SOLID
        ic%mc%rvx(k) = ic%rvel(1, p%mat(ip))
        ic%mc%rvy(k) = ic%rvel(2, p%mat(ip))
      end do
    end subroutine mark_rigid
  end subroutine p2g_faces

  pure subroutine face_slot(sh, ip, a, k, w, gx, gy, ok)
    !! Node, weight and gradient of slot a of particle ip (shape_slot's order: main slot a, or
    !! pool slot a - nm); ok = .false. past its last slot. In this module so that the transfers'
    !! loops inline it (shape_slot, in cpdi_shape, was called per slot).
    type(shape_t), intent(in) :: sh
    integer(ik), intent(in) :: ip, a
    integer(ik), intent(out) :: k
    real(wp), intent(out) :: w, gx, gy
    logical, intent(out) :: ok
    integer(ik) :: c
    ok = .true.
    if (a <= sh%nm) then
      k = sh%idx(a, ip)
      w = sh%w(a, ip)
      gx = sh%gx(a, ip)
      gy = sh%gy(a, ip)
      return
    end if
    c = sh%ovf(ip)
    ok = c /= 0
    k = 0
    w = 0.0_wp
    gx = 0.0_wp
    gy = 0.0_wp
    if (.not. ok) return
    k = sh%pidx(a - sh%nm, c)
    w = sh%pw(a - sh%nm, c)
    gx = sh%pgx(a - sh%nm, c)
    gy = sh%pgy(a - sh%nm, c)
  end subroutine face_slot

  integer(ik) function p2g_rows(ic, p, g, ip) result(span)
    !! Sets prow(ip), the lowest row (0-based, of the faces and cells, which share one numbering)
    !! that particle ip's P2G writes: its stencils on both face lattices, its centre's cell and
    !! its fill cells (incomp_fill_weights' rows). Returns the rows it spans above that one.
    type(incomp_t), intent(inout) :: ic
    type(particles_t), intent(in) :: p
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: ip
    integer(ik) :: lo, hi, jc, j0
    real(wp) :: y
    y = (p%x(2, ip) - g%gorig(2))/g%h
    jc = int(y)
    j0 = int(floor(y - 0.5_wp)) + 1
    lo = min(ic%shu%row(ip), ic%shv%row(ip), jc, min(max(j0, ic%mc%lo(2)), ic%mc%hi(2)) - 1)
    hi = max(ic%shu%row(ip) + ic%shu%span, ic%shv%row(ip) + ic%shv%span, jc, &
             min(max(j0 + 1, ic%mc%lo(2)), ic%mc%hi(2)) - 1)
    ic%prow(ip) = max(lo, 0_ik)
    span = hi - ic%prow(ip)
  end function p2g_rows

  subroutine p2g_particle(ic, p, g, ip, dt, gravity, apic, batty, av)
    !! P2G of particle ip to the faces and cells (p2g_faces), rigid particles excepted.
    type(incomp_t), intent(inout) :: ic
    type(particles_t), intent(in) :: p
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: ip
    real(wp), intent(in) :: dt, gravity(2), av
    logical, intent(in) :: apic, batty
    integer(ik) :: a, k, i, j, kc(4)
    real(wp) :: mp, vp, sx(2), wc(4)
    logical :: solid
    mp = p%m(ip)
    vp = p%vol0(ip)
    solid = .false.
    if (ic%coupled) then
      if (ic%rigid(p%mat(ip))) return   ! marked after the water (p2g_faces mark_rigid)
      solid = ic%solid(p%mat(ip)) .or. ic%free(p%mat(ip))
      vp = p%vol(ip)
      if (ic%free(p%mat(ip))) then   ! volume only: the body's mass is its own (cpdi_rigid_body)
        call scatter_v(ic%shu, ic%uvs)
        call scatter_v(ic%shv, ic%vvs)
        call scatter_v(ic%shu, ic%rb%uvb(:, ic%rb%slot(ip)))
        call scatter_v(ic%shv, ic%rb%vvb(:, ic%rb%slot(ip)))
      else if (solid) then
        call scatter_v(ic%shu, ic%uvs, ic%usm)
        call scatter_v(ic%shv, ic%vvs, ic%vsm)
      else
        call scatter_v(ic%shu, ic%uvw)
        call scatter_v(ic%shv, ic%vvw)
      end if
    end if
    if (ic%sep) then
      call scatter_sep(ic%gu, 1, ic%mc%um, ic%mc%u, ic%mc%uo)
      call scatter_sep(ic%gv, 2, ic%mc%vm, ic%mc%v, ic%mc%vo)
    else if (.not. solid) then
      call scatter(ic%shu, ic%gu, 1, ic%mc%um, ic%mc%u, ic%mc%uo)
      call scatter(ic%shv, ic%gv, 2, ic%mc%vm, ic%mc%v, ic%mc%vo)
    end if
    ! cell of the particle, and its volume spread bilinearly over the cell centres (indices
    ! clamped to the physical cells: a wall mirrors the water beyond it)
    sx = (p%x(:, ip) - g%gorig)/g%h
    i = int(sx(1)) + 1
    j = int(sx(2)) + 1
    if (i >= ic%mc%lo(1) .and. i <= ic%mc%hi(1) .and. j >= ic%mc%lo(2) .and. j <= ic%mc%hi(2) .and. &
        .not. (solid .and. batty)) ic%mc%cell(i + (j - 1)*ic%mc%nn(1)) = CELL_FLUID
    call incomp_fill_weights(ic%mc, g, p%x(:, ip), kc, wc)
    do a = 1, 4
      k = kc(a)
      ic%mc%fill(k) = ic%mc%fill(k) + wc(a)*vp*av
      if (ic%coupled .and. .not. solid) ic%fillw(k) = ic%fillw(k) + wc(a)*vp*av
    end do
  contains
    subroutine scatter_v(sh, fv, fm)
      !! Volume (fv) and, if given, mass (fm) of particle ip to a face lattice (slots as in
      !! scatter).
      type(shape_t), intent(in) :: sh
      real(wp), intent(inout) :: fv(:)
      real(wp), intent(inout), optional :: fm(:)
      real(wp) :: w, gxk, gyk
      integer(ik) :: kk
      logical :: ok
      do a = 1, sh%ns
        call face_slot(sh, ip, a, kk, w, gxk, gyk, ok)
        if (.not. ok) exit
        if (present(fm)) fm(kk) = fm(kk) + w*mp
        fv(kk) = fv(kk) + w*vp
      end do
    end subroutine scatter_v

    subroutine scatter(sh, gl, c, fm, fq, fi)
      !! Velocity component c of particle ip to its face lattice gl: mass fm, momentum fq
      !! (APIC: with the affine part, c's row of the particle's L) and force impulse fi. The
      !! slots in shape_slot's order (main, then pool), read from the arrays directly; a
      !! node's position as grid_node_x gives it.
      type(shape_t), intent(in) :: sh
      type(grid_t), intent(in) :: gl
      integer(ik), intent(in) :: c
      real(wp), intent(inout) :: fm(:), fq(:), fi(:)
      real(wp) :: v, lx, ly, gb, w, mom, gxk, gyk
      integer(ik) :: nx, kk
      logical :: ok
      v = p%v(c, ip)
      lx = p%L(c, ip)
      ly = p%L(c + 2, ip)
      nx = gl%nn(1)
      gb = gravity(c) + p%bf(c, ip)
      do a = 1, sh%ns
        call face_slot(sh, ip, a, kk, w, gxk, gyk, ok)
        if (.not. ok) exit
        mom = v
        if (apic) mom = mom + lx*((gl%gorig(1) + real(mod(kk - 1, nx), wp)*gl%h) - p%x(1, ip)) &
                            + ly*((gl%gorig(2) + real((kk - 1)/nx, wp)*gl%h) - p%x(2, ip))
        fm(kk) = fm(kk) + w*mp
        fq(kk) = fq(kk) + w*mp*mom
        fi(kk) = fi(kk) + w*mp*dt*gb
      end do
    end subroutine scatter

    subroutine scatter_sep(gl, c, fm, fq, fi)
      !! scatter with the separable weights (ic%sep): the 3 x 3 faces from sep_axis's factors,
      !! in scatter's slot order (x fastest).
      type(grid_t), intent(in) :: gl
      integer(ik), intent(in) :: c
      real(wp), intent(inout) :: fm(:), fq(:), fi(:)
      real(wp) :: v, lx, ly, gb, w, mom, rh, sx(3), dx(3), sy(3), dy(3), yn, mgb
      integer(ik) :: i0, j0, b, kk
      rh = 1.0_wp/gl%h
      call sep_axis(p%x(1, ip), p%r(1, ip), gl%gorig(1), rh, i0, sx, dx)
      call sep_axis(p%x(2, ip), p%r(4, ip), gl%gorig(2), rh, j0, sy, dy)
      v = p%v(c, ip)
      lx = p%L(c, ip)
      ly = p%L(c + 2, ip)
      gb = gravity(c) + p%bf(c, ip)
      mgb = mp*dt*gb
      do b = 1, 3
        yn = (gl%gorig(2) + real(j0 + b - 1, wp)*gl%h) - p%x(2, ip)
        do a = 1, 3
          kk = i0 + a + (j0 + b - 1)*gl%nn(1)
          w = sx(a)*sy(b)
          mom = v
          if (apic) mom = mom + lx*((gl%gorig(1) + real(i0 + a - 1, wp)*gl%h) - p%x(1, ip)) + ly*yn
          fm(kk) = fm(kk) + w*mp
          fq(kk) = fq(kk) + w*mp*mom
          fi(kk) = fi(kk) + w*mgb
        end do
      end do
    end subroutine scatter_sep
  end subroutine p2g_particle

  subroutine face_velocities(mc, mtol)
    !! Momenta to velocities: uo <- velocity before forces, u <- after forces.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: mtol
    where (mc%um > mtol)
      mc%u = mc%u/mc%um
      mc%uo = mc%u + mc%uo/mc%um
    elsewhere
      mc%u = 0.0_wp
      mc%uo = 0.0_wp
    end where
    where (mc%vm > mtol)
      mc%v = mc%v/mc%vm
      mc%vo = mc%v + mc%vo/mc%vm
    elsewhere
      mc%v = 0.0_wp
      mc%vo = 0.0_wp
    end where
    call swap(mc%u, mc%uo)
    call swap(mc%v, mc%vo)
  end subroutine face_velocities

  subroutine swap(a, b)
    !! Exchange the values of two arrays of one size.
    real(wp), intent(inout) :: a(:), b(:)
    real(wp) :: t
    integer :: i
    do i = 1, size(a)
      t = a(i)
      a(i) = b(i)
      b(i) = t
    end do
  end subroutine swap

  subroutine viscosity(mc, nu_dt, mtol)
    !! u <- u + dt nu Laplacian(u) on faces whose four lattice neighbours carry mass
    !! (explicit; the step respects the viscous limit). pe and b serve as scratch.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: nu_dt, mtol
    real(wp) :: c
    c = nu_dt/mc%h**2
    call lap(mc%u, mc%um, mc%pe)
    call lap(mc%v, mc%vm, mc%b)
  contains
    subroutine lap(w, wm, tmp)
      real(wp), intent(inout) :: w(:), tmp(:)
      real(wp), intent(in) :: wm(:)
      integer(ik) :: i, j, k, n1
      n1 = mc%nn(1)
      tmp = w
      do j = 2, mc%nn(2) - 1
        do i = 2, n1 - 1
          k = i + (j - 1)*n1
          if (wm(k) > mtol .and. wm(k - 1) > mtol .and. wm(k + 1) > mtol .and. wm(k - n1) > mtol .and. &
              wm(k + n1) > mtol) &
            w(k) = tmp(k) + c*(tmp(k - 1) + tmp(k + 1) + tmp(k - n1) + tmp(k + n1) - 4.0_wp*tmp(k))
        end do
      end do
    end subroutine lap
  end subroutine viscosity

  subroutine incomp_step(ic, g, p, flip, gravity, dt, steps, diag, timers, smax, st, nm, nvx, nvy, dvx, dvy)
    !! One semi-implicit step of length dt. diag and timers follow cpdi_step's layout.
    !! Coupled runs (cpdi_fsi) pass the solids' nodal mass nm and velocity after their explicit
    !! forces (nvx, nvy) and receive the nodal velocity increments of the projection (dvx, dvy).
    type(incomp_t), intent(inout) :: ic
    real(wp), intent(in), optional :: nm(:), nvx(:), nvy(:)
    real(wp), intent(inout), optional :: dvx(:), dvy(:)
    type(grid_t), intent(in) :: g
    type(particles_t), intent(inout) :: p
    real(wp), intent(in) :: flip, gravity(2), dt
    integer(int64), intent(in) :: steps
    real(wp), intent(inout) :: diag(:), timers(:)
    real(wp), intent(out) :: smax
    type(status_t), intent(inout) :: st
    real(wp) :: mtol
    logical :: converged, batty, changed
    character(len=400) :: buf
    integer(int64) :: t0
    integer(ik) :: sweep

    call tic(t0)
    call weights(ic, p, steps, st)
    if (.not. st%ok()) return
    call toc(timers, TIMER_SHAPE, t0)
    mtol = 1.0e-12_wp*minval(p%m)
    call p2g_faces(ic, p, g, dt, gravity, ic%transfer == TRANSFER_APIC)
    call face_velocities(ic%mc, mtol)
    call toc(timers, TIMER_P2G, t0)
    if (ic%visc > 0.0_wp) call viscosity(ic%mc, dt*ic%visc/ic%rho, mtol)
    batty = ic%coupled .and. ic%coupling == COUPLING_BATTY
    if (batty) then
      call batty_faces(ic, nm, nvx, nvy, mtol)
      if (ic%rb%n > 0) then
        call water_faces_without_water(ic%mc, ic%mc%um, ic%wu, 1_ik, ic%mc%u, ic%mc%uo, mtol, dt*gravity(1))
        call water_faces_without_water(ic%mc, ic%mc%vm, ic%wv, ic%mc%nn(1), ic%mc%v, ic%mc%vo, mtol, dt*gravity(2))
      end if
    else if (ic%coupled) then
      call solid_to_faces(ic, nm, nvx, nvy, mtol)
    end if
    diag(DIAG_CG_ITERATIONS) = 0.0_wp
    ic%mc%nlr = 0   ! the correction's solve holds the bodies still
    call volume_correction(ic, dt, mtol, diag, converged, timers, t0)
    if (converged) then
      call mac_walls(ic%mc)
      if (batty) then
        call cpl_assemble(ic%mc, dt, ic%rho, ic%wu, ic%wv, ic%usm, ic%vsm, ic%us, ic%vs, mtol, .true., 0.0_wp)
        call rb_assemble(ic%rb, ic%mc, g, ic%wu, ic%wv, ic%uvs, ic%vvs, ic%rho, dt)
      else
        call mac_assemble(ic%mc, dt, ic%rho, 0.0_wp)
        if (ic%coupled .and. ic%submode == SUBSTEPS_IMPLICIT) call solid_helmholtz(ic, dt)
      end if
      call toc(timers, TIMER_GRID, t0)
      call mac_solve(ic%mc, ic%tol, ic%maxit, converged)
      call toc(timers, TIMER_PRESSURE, t0)
      diag(DIAG_CG_ITERATIONS) = diag(DIAG_CG_ITERATIONS) + real(ic%mc%iters, wp)
      diag(DIAG_CG_RESIDUAL) = ic%mc%resid
      diag(DIAG_CG_TOTAL) = diag(DIAG_CG_TOTAL) + real(ic%mc%iters, wp)
      if (batty .and. ic%rb%n > 0) then   ! the water leaves a free body next to the void
        do sweep = 1, SEPARATION_SWEEPS
          if (.not. converged) exit
          call separate_from_bodies(ic, changed)
          if (.not. changed) exit
          call cpl_assemble(ic%mc, dt, ic%rho, ic%wu, ic%wv, ic%usm, ic%vsm, ic%us, ic%vs, mtol, .true., 0.0_wp)
          call rb_assemble(ic%rb, ic%mc, g, ic%wu, ic%wv, ic%uvs, ic%vvs, ic%rho, dt)
          call mac_solve(ic%mc, ic%tol, ic%maxit, converged)
          diag(DIAG_CG_ITERATIONS) = diag(DIAG_CG_ITERATIONS) + real(ic%mc%iters, wp)
          diag(DIAG_CG_RESIDUAL) = ic%mc%resid
          diag(DIAG_CG_TOTAL) = diag(DIAG_CG_TOTAL) + real(ic%mc%iters, wp)
        end do
      end if
    end if
    if (.not. converged) then
      write (buf, '(a,i0,a,es10.3,a,i0,a,es9.2,a)') 'step ', steps + 1, ': the pressure solve did not converge '// &
        '(relative residual ', ic%mc%resid, ' after ', ic%mc%iters, ' CG iterations, tolerance ', ic%tol, &
        '); reduce [solver] cfl, or raise [solver] cg_max_iterations or cg_tolerance'
      call st%set(CPDI_ERR_SOLVE, trim(buf))
      return
    end if
    call mac_project(ic%mc, dt, ic%rho)
    if (batty) then
      call rb_impulse(ic%rb, ic%mc, dt)
      call batty_to_solid(ic, g, nm, dt, mtol, dvx, dvy)
    else if (ic%coupled) then
      call faces_to_solid(ic, nm, mtol, dvx, dvy)
    end if
    where (ic%mc%uval /= 0)   ! FLIP increments of the faces the projection set
      ic%mc%uo = ic%mc%u - ic%mc%uo
    elsewhere
      ic%mc%uo = 0.0_wp
    end where
    where (ic%mc%vval /= 0)
      ic%mc%vo = ic%mc%v - ic%mc%vo
    elsewhere
      ic%mc%vo = 0.0_wp
    end where
    call mac_extrapolate(ic%mc, ic%mc%u, ic%mc%uval, EXTRAPOLATION_LAYERS)
    call mac_extrapolate(ic%mc, ic%mc%uo, ic%mc%uval, EXTRAPOLATION_LAYERS)
    call mac_extrapolate(ic%mc, ic%mc%v, ic%mc%vval, EXTRAPOLATION_LAYERS)
    call mac_extrapolate(ic%mc, ic%mc%vo, ic%mc%vval, EXTRAPOLATION_LAYERS)
    call mac_constrain(ic%mc, ic%mc%u, ic%mc%v, .false.)   ! inside solids: their normal velocity
    call mac_constrain(ic%mc, ic%mc%uo, ic%mc%vo, .true.)   ! (no FLIP increment there)
    call mac_ghost_pressure(ic%mc)
    call toc(timers, TIMER_GRID, t0)
    call g2p_faces(ic, g, p, flip, dt, gravity, diag, smax, st, steps)
    call toc(timers, TIMER_G2P, t0)
  end subroutine incomp_step

  subroutine separate_from_bodies(ic, changed)
    !! The water leaves a free body where it would have to pull on it next to the void (the void
    !! stands for air at the ambient pressure, p = 0, so water touching both can only push): a
    !! water cell the body bounds (an entry of the low-rank term) with p < 0 and a face open to a
    !! cell of air that the solid does not fill (the void, not the body's inside) becomes air, and
    !! the faces between water and the body's inside it uncovers are closed. Water that touches
    !! the body away from the void keeps to it (a submerged body drags its wake). changed: some
    !! cell became air (the system is to be assembled and solved again).
    type(incomp_t), intent(inout) :: ic
    logical, intent(out) :: changed
    integer(ik), parameter :: LEAVING = -1
    integer(ik) :: e, c, n1, a, nb(4)
    real(wp) :: af(4)
    changed = .false.
    n1 = ic%mc%nn(1)
    associate (mc => ic%mc)
      do e = 1, mc%nlr
        c = mc%lrc(e)
        if (mc%cell(c) /= CELL_FLUID .or. .not. (mc%p(c) < 0.0_wp)) cycle
        nb = [c - 1, c + 1, c - n1, c + n1]
        af = [1.0_wp - ic%wu(c), 1.0_wp - ic%wu(c + 1), 1.0_wp - ic%wv(c), 1.0_wp - ic%wv(c + n1)]
        do a = 1, 4
          if (mc%cell(nb(a)) == CELL_AIR .and. ic%sfill(nb(a)) < 0.5_wp .and. af(a) > 0.0_wp) then
            mc%cell(c) = LEAVING
            changed = .true.
            exit
          end if
        end do
      end do
      where (mc%cell == LEAVING) mc%cell = CELL_AIR
      where (mc%cell == CELL_AIR) mc%p = 0.0_wp
    end associate
    if (changed) call cpl_close(ic%mc, ic%wu, ic%wv, ic%sfill)
  end subroutine separate_from_bodies

  subroutine solid_helmholtz(ic, dt)
    !! solid_substeps = "implicit": the solids' volumetric stress inside the projection (after
    !! Stomakhin et al. 2014, their pressure equation for a compressible phase). A cell of solid
    !! volume fraction phi changes its volume at the solid's rate, div v = -phi (p - p^n) / (K dt)
    !! (backward Euler of dp = -K dJ / J, K the solid's in-plane bulk stiffness, p^n its in-plane
    !! mean pressure at t^n); with v = v* - (dt / rho) a grad p that is
    !!   A p + (rho h^2 / dt^2) (phi / K) p = (rho h^2 / dt) (-div v*) + (rho h^2 / dt^2) (phi / K) p^n,
    !! a positive term on A's diagonal (A stays symmetric positive definite). cmp = phi / K and
    !! cmpp = phi p^n / K per cell come from cpdi_fsi (solid_compliance). The pressure in a solid
    !! cell is then the solid's volumetric stress at t^n+1; the predictor carried only its
    !! deviatoric stress (cpdi_fsi solid_p2g), and so do the substeps (cpdi_step, sim_t%devonly).
    type(incomp_t), intent(inout) :: ic
    real(wp), intent(in) :: dt
    integer(ik) :: i, j, c, n1
    real(wp) :: scale
    n1 = ic%mc%nn(1)
    scale = ic%rho*ic%mc%h**2/dt**2
    do j = ic%mc%lo(2), ic%mc%hi(2)
      do i = ic%mc%lo(1), ic%mc%hi(1)
        c = i + (j - 1)*n1
        if (ic%mc%cell(c) /= CELL_FLUID) cycle
        if (ic%cmp(c) <= 0.0_wp) cycle
        ic%mc%adiag(c) = ic%mc%adiag(c) + scale*ic%cmp(c)
        ic%mc%b(c) = ic%mc%b(c) + scale*ic%cmpp(c)
      end do
    end do
  end subroutine solid_helmholtz

  subroutine solid_to_faces(ic, nm, nvx, nvy, mtol)
    !! The single continuum: on every face the solid reaches, its mass (us from the nodal
    !! velocity nvx, nvy, weighted by the nodal mass nm of the face's two nodes) joins the
    !! water's; the face velocity is the mixture's momentum over its mass and its coefficient
    !! rho_w V / m (the projection's dt / rho_face). Water-only faces keep coefficient 1.
    !! A face of solid only takes the mixture velocity before forces too (uo), so the water's
    !! FLIP increment there is the projection's change alone.
    type(incomp_t), intent(inout) :: ic
    real(wp), intent(in) :: nm(:), nvx(:), nvy(:), mtol
    integer(ik) :: i, j, k, n1, kb
    real(wp) :: mt, wn
    n1 = ic%mc%nn(1)
    associate (mc => ic%mc)
      do j = 1, mc%nn(2) - 1
        do i = 1, n1 - 1
          k = i + (j - 1)*n1
          ic%us(k) = 0.0_wp
          ic%vs(k) = 0.0_wp
          ic%umx(k) = mc%u(k)
          ic%vmx(k) = mc%v(k)
          if (ic%usm(k) > mtol) then   ! u face k: between nodes k and k + n1
            kb = k + n1
            wn = nm(k) + nm(kb)
            if (wn > 0.0_wp) ic%us(k) = (nm(k)*nvx(k) + nm(kb)*nvx(kb))/wn
            mt = mc%um(k) + ic%usm(k)
            mc%u(k) = (mc%um(k)*mc%u(k) + ic%usm(k)*ic%us(k))/mt
            if (.not. (mc%um(k) > mtol)) mc%uo(k) = mc%u(k)
            mc%ua(k) = ic%rho*(ic%uvw(k) + ic%uvs(k))/mt
            ic%umx(k) = mc%u(k)
          end if
          if (ic%vsm(k) > mtol) then   ! v face k: between nodes k and k + 1
            kb = k + 1
            wn = nm(k) + nm(kb)
            if (wn > 0.0_wp) ic%vs(k) = (nm(k)*nvy(k) + nm(kb)*nvy(kb))/wn
            mt = mc%vm(k) + ic%vsm(k)
            mc%v(k) = (mc%vm(k)*mc%v(k) + ic%vsm(k)*ic%vs(k))/mt
            if (.not. (mc%vm(k) > mtol)) mc%vo(k) = mc%v(k)
            mc%va(k) = ic%rho*(ic%vvw(k) + ic%vvs(k))/mt
            ic%vmx(k) = mc%v(k)
          end if
        end do
      end do
    end associate
  end subroutine solid_to_faces

  subroutine water_faces_without_water(mc, fm, w, normal, f, fo, mtol, gdt)
    !! A face of a water cell whose water share 1 - w is open but that no water particle reaches
    !! (beside a solid that covers most of it) carries the mean velocity of its lattice neighbours
    !! that water reaches (f after forces, fo before), or gravity's impulse gdt alone: not 0, which
    !! the constraint would read as water held still there (a body at rest in resting water off the
    !! cell lines then felt 0.4 % less than its buoyancy). normal: the lattice stride across the face.
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: fm(:), w(:), mtol, gdt
    integer(ik), intent(in) :: normal
    real(wp), intent(inout) :: f(:), fo(:)
    integer(ik) :: i, j, k, n1, a, cnt, nb(4)
    real(wp) :: sf, so
    n1 = mc%nn(1)
    do j = mc%lo(2), mc%hi(2) + 1
      do i = mc%lo(1), mc%hi(1) + 1
        k = i + (j - 1)*n1
        if (fm(k) > mtol .or. .not. (w(k) < 1.0_wp)) cycle
        if (mc%cell(k) /= CELL_FLUID .and. mc%cell(k - normal) /= CELL_FLUID) cycle
        if (mc%cell(k) == CELL_SOLID .or. mc%cell(k - normal) == CELL_SOLID) cycle
        nb = [k - 1, k + 1, k - n1, k + n1]
        cnt = 0
        sf = 0.0_wp
        so = 0.0_wp
        do a = 1, 4
          if (fm(nb(a)) > mtol) then
            cnt = cnt + 1
            sf = sf + f(nb(a))
            so = so + fo(nb(a))
          end if
        end do
        if (cnt > 0) then
          f(k) = sf/real(cnt, wp)
          fo(k) = so/real(cnt, wp)
        else
          f(k) = gdt
          fo(k) = 0.0_wp
        end if
      end do
    end do
  end subroutine water_faces_without_water

  subroutine batty_faces(ic, nm, nvx, nvy, mtol)
    !! Coupling batty (cpdi_coupling): the solid's face velocities (us, vs: the nodal velocity
    !! nvx, nvy of the face's two nodes, weighted by their mass nm), the face and cell solid
    !! fractions and the water cells from the water's own fill. The water's faces keep the
    !! water's velocity (coefficient 1).
    type(incomp_t), intent(inout) :: ic
    real(wp), intent(in) :: nm(:), nvx(:), nvy(:), mtol
    integer(ik) :: i, j, k, n1, kb
    real(wp) :: wn
    n1 = ic%mc%nn(1)
    do j = 1, ic%mc%nn(2) - 1
      do i = 1, n1 - 1
        k = i + (j - 1)*n1
        ic%us(k) = 0.0_wp
        ic%vs(k) = 0.0_wp
        if (ic%usm(k) > mtol) then   ! u face k: between nodes k and k + n1
          kb = k + n1
          wn = nm(k) + nm(kb)
          if (wn > 0.0_wp) ic%us(k) = (nm(k)*nvx(k) + nm(kb)*nvx(kb))/wn
        end if
        if (ic%vsm(k) > mtol) then   ! v face k: between nodes k and k + 1
          kb = k + 1
          wn = nm(k) + nm(kb)
          if (wn > 0.0_wp) ic%vs(k) = (nm(k)*nvy(k) + nm(kb)*nvy(kb))/wn
        end if
      end do
    end do
    call cpl_fractions(ic%mc, ic%uvs, ic%vvs, ic%wu, ic%wv, ic%phi)
    call cpl_classify(ic%mc, ic%fillw, ic%phi, ic%wu, ic%wv, ic%sfill)
  end subroutine batty_faces

  subroutine batty_to_solid(ic, g, nm, dt, mtol, dvx, dvy)
    !! Coupling batty, after the projection: the pressure's impulse on each free solid face goes
    !! to the face's two nodes as momentum, in the shares their mass gave the face's velocity
    !! (dv_n = I_f / (m_n + m_n')); dvx, dvy: the nodal velocity change. The water velocity of
    !! faces inside the solid (w = 1) is not the water's: they are extrapolated like faces in air.
    type(incomp_t), intent(inout) :: ic
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: nm(:), dt, mtol
    real(wp), intent(inout) :: dvx(:), dvy(:)
    integer(ik) :: i, j, k, n1, kb
    real(wp) :: wn, d
    n1 = ic%mc%nn(1)
    call cpl_impulse(ic%mc, dt, ic%wu, ic%wv, ic%usm, ic%vsm, mtol, ic%iu, ic%iv)
    dvx = 0.0_wp
    dvy = 0.0_wp
    do j = 1, ic%mc%nn(2) - 1
      do i = 1, n1 - 1
        k = i + (j - 1)*n1
        if (ic%iu(k) /= 0.0_wp) then
          kb = k + n1
          wn = nm(k) + nm(kb)
          if (wn > mtol) then
            d = ic%iu(k)/wn
            dvx(k) = dvx(k) + d
            dvx(kb) = dvx(kb) + d
          end if
        end if
        if (ic%iv(k) /= 0.0_wp) then
          kb = k + 1
          wn = nm(k) + nm(kb)
          if (wn > mtol) then
            d = ic%iv(k)/wn
            dvy(k) = dvy(k) + d
            dvy(kb) = dvy(kb) + d
          end if
        end if
      end do
    end do
    call grid_apply_walls(g, dvx, dvy, ic%svol, ic%vfull)   ! the walls as in the solid's own step
    where (ic%wu >= 1.0_wp) ic%mc%uval = 0
    where (ic%wv >= 1.0_wp) ic%mc%vval = 0
  end subroutine batty_to_solid

  subroutine faces_to_solid(ic, nm, mtol, dvx, dvy)
    !! After the projection: each solid face's velocity change (the shared face velocity minus
    !! the solid's own) goes back to its two nodes, averaged over a node's faces by solid face
    !! mass.
    type(incomp_t), intent(inout) :: ic
    real(wp), intent(in) :: nm(:), mtol
    real(wp), intent(inout) :: dvx(:), dvy(:)
    integer(ik) :: i, j, k, n1, kb
    real(wp) :: d, wm
    n1 = ic%mc%nn(1)
    dvx = 0.0_wp
    dvy = 0.0_wp
    ic%nwx = 0.0_wp
    ic%nwy = 0.0_wp
    associate (mc => ic%mc)
      do j = 1, mc%nn(2) - 1
        do i = 1, n1 - 1
          k = i + (j - 1)*n1
          if (ic%usm(k) > mtol) then
            kb = k + n1
            d = mc%u(k) - ic%us(k)
            ic%us(k) = d   ! from here on: the solid's velocity change on the face
            wm = ic%usm(k)
            dvx(k) = dvx(k) + wm*d
            dvx(kb) = dvx(kb) + wm*d
            ic%nwx(k) = ic%nwx(k) + wm
            ic%nwx(kb) = ic%nwx(kb) + wm
          end if
          if (ic%vsm(k) > mtol) then
            kb = k + 1
            d = mc%v(k) - ic%vs(k)
            ic%vs(k) = d
            wm = ic%vsm(k)
            dvy(k) = dvy(k) + wm*d
            dvy(kb) = dvy(kb) + wm*d
            ic%nwy(k) = ic%nwy(k) + wm
            ic%nwy(kb) = ic%nwy(kb) + wm
          end if
        end do
      end do
    end associate
    where (ic%nwx > 0.0_wp .and. nm > 0.0_wp)
      dvx = dvx/ic%nwx
    elsewhere
      dvx = 0.0_wp
    end where
    where (ic%nwy > 0.0_wp .and. nm > 0.0_wp)
      dvy = dvy/ic%nwy
    elsewhere
      dvy = 0.0_wp
    end where
  end subroutine faces_to_solid

  subroutine volume_correction(ic, dt, mtol, diag, converged, timers, t0)
    !! The velocity field (uc, vc) whose divergence is beta (fill - 1) / dt in over-filled
    !! water cells and 0 elsewhere (a solve with the same operator and only that target). It
    !! moves the particles apart again but is not added to their velocities, so a packing
    !! error is undone without a force on the flow (a divergence target inside the physical
    !! solve measured a dam-break front 0.08-0.25 T ahead, growing with beta).
    !! Solved to a relative residual correction_tolerance (1e-4) rather than cg_tolerance: the field is the
    !! projection of an exact pressure gradient whatever the residual (curl-free, walls' normal
    !! velocity exact), only its divergence misses the target, by at most 1e-4 of the target's
    !! norm; the target itself undoes only beta of the packing error a step and is measured
    !! again from the particles next step, so what the looser solve leaves is 1e-4 of a step's
    !! correction, fed back like the (1 - beta) left on purpose. It halves the solve's iterations
    !! (docs/notes/pressure_multigrid.md). Water alone only: coupled runs keep cg_tolerance (the
    !! correction keeps the water out of the solids' cells there; at 1e-4 sinking_block's settled
    !! block moved 2 mm and floating_block's tilt grew from 1e-8 to 1e-5 degrees).
    type(incomp_t), intent(inout) :: ic
    real(wp), intent(in) :: dt, mtol
    real(wp), intent(inout) :: diag(:), timers(:)
    logical, intent(out) :: converged
    integer(int64), intent(inout) :: t0
    real(wp) :: dtc
    converged = .true.
    ic%mc%uc = 0.0_wp
    ic%mc%vc = 0.0_wp
    if (ic%beta == 0.0_wp) return
    if (ic%coupled .and. ic%coupling == COUPLING_BATTY) then
      call batty_correction()
      return
    end if
    if (ic%coupled .and. ic%subcycled) then
      ! subcycled: the cell's total fill, water and solid, must stay <= 1 (water that ran into a
      ! solid's cells is pushed out again; the solids move in their own substeps, not with this)
      ic%fillw = ic%mc%fill
    end if
    if (ic%coupled) then   ! the water's own over-filling only: a solid's volume is not packing
      if (.not. any(ic%fillw > 1.0_wp .and. ic%mc%cell == CELL_FLUID)) return
    else
      if (.not. any(ic%mc%fill > 1.0_wp .and. ic%mc%cell == CELL_FLUID)) return
    end if
    call swap(ic%mc%u, ic%mc%uc)   ! u, v: zero; uc, vc: the flow's face velocities
    call swap(ic%mc%v, ic%mc%vc)
    dtc = dt
    if (ic%coupled) then
      ! coupled runs step at the solid's acoustic limit, far below the water's own step: the
      ! packing error is undone at the water's rate beta / (its own step), not beta per
      ! (tiny) step, which moved water ~ beta (fill - 1) h every step and lifted it (cpdi_fsi)
      dtc = max(dt, ic%dt_corr)
      call mac_assemble(ic%mc, dtc, ic%rho, ic%beta, ic%fillw)
    else
      call mac_assemble(ic%mc, dt, ic%rho, ic%beta)
    end if
    call toc(timers, TIMER_GRID, t0)
    if (ic%coupled) then   ! the solids' packing against the water: to the run's tolerance
      call mac_solve(ic%mc, ic%tol, ic%maxit, converged)
    else
      call mac_solve(ic%mc, opt_value(ic%mc%ov, 'correction_tolerance'), ic%maxit, converged)
    end if
    call toc(timers, TIMER_PRESSURE, t0)
    diag(DIAG_CG_ITERATIONS) = real(ic%mc%iters, wp)
    diag(DIAG_CG_TOTAL) = diag(DIAG_CG_TOTAL) + real(ic%mc%iters, wp)
    if (converged) then
      call mac_project(ic%mc, dtc, ic%rho, still=.true.)
      call mac_extrapolate(ic%mc, ic%mc%u, ic%mc%uval, EXTRAPOLATION_LAYERS)
      call mac_extrapolate(ic%mc, ic%mc%v, ic%mc%vval, EXTRAPOLATION_LAYERS)
      call mac_constrain(ic%mc, ic%mc%u, ic%mc%v, .true.)
    end if
    call swap(ic%mc%u, ic%mc%uc)
    call swap(ic%mc%v, ic%mc%vc)
  contains
    subroutine batty_correction()
      !! The packing error, fill_w + fill_s - 1 (clamped to +-1/2), undone at the water's
      !! rate with the solid held still: two-sided inside the water (a gap next to a solid fills),
      !! over-filling only next to air (the surface is not pulled down).
      call swap(ic%mc%u, ic%mc%uc)
      call swap(ic%mc%v, ic%mc%vc)
      dtc = max(dt, ic%dt_corr)
      call cpl_assemble(ic%mc, dtc, ic%rho, ic%wu, ic%wv, ic%usm, ic%vsm, ic%us, ic%vs, mtol, .false., ic%beta, &
                        ic%fillw, ic%sfill)
      call toc(timers, TIMER_GRID, t0)
      call mac_solve(ic%mc, ic%tol, ic%maxit, converged)
      call toc(timers, TIMER_PRESSURE, t0)
      diag(DIAG_CG_ITERATIONS) = real(ic%mc%iters, wp)
      diag(DIAG_CG_TOTAL) = diag(DIAG_CG_TOTAL) + real(ic%mc%iters, wp)
      if (converged) then
        call mac_project(ic%mc, dtc, ic%rho, still=.true.)
        where (ic%wu >= 1.0_wp) ic%mc%uval = 0   ! the solid's inside: no water velocity of its own
        where (ic%wv >= 1.0_wp) ic%mc%vval = 0
        call mac_extrapolate(ic%mc, ic%mc%u, ic%mc%uval, EXTRAPOLATION_LAYERS)
        call mac_extrapolate(ic%mc, ic%mc%v, ic%mc%vval, EXTRAPOLATION_LAYERS)
        call mac_constrain(ic%mc, ic%mc%u, ic%mc%v, .true.)
      end if
      call swap(ic%mc%u, ic%mc%uc)
      call swap(ic%mc%v, ic%mc%vc)
    end subroutine batty_correction
  end subroutine volume_correction

  subroutine g2p_faces(ic, g, p, flip, dt, gravity, diag, smax, st, steps)
    !! Velocities, affine matrices (stored as L) and positions of every particle; particle
    !! pressure from the cells; kinetic energy, momentum and works (block by block).
    type(incomp_t), intent(inout) :: ic
    type(grid_t), intent(in) :: g
    type(particles_t), intent(inout) :: p
    real(wp), intent(in) :: flip, dt, gravity(2)
    real(wp), intent(inout) :: diag(:)
    real(wp), intent(out) :: smax
    type(status_t), intent(inout) :: st
    integer(int64), intent(in) :: steps
    integer(ik) :: c, lo, hi, ip, a, k, nclamp, i0, j0, i, j, bad(NCHUNK), ix(2), jy(2)
    real(wp) :: vn(2), dv(2), vc(2), cu(2), cv(2), w, gxk, gyk, xo(2), xmin(2), xmax(2), ke, mom(2), wg, wb, mp, &
                s(2), pp, wx(2), wy(2), vmax, wc
    logical :: closed(4), apic
    character(len=300) :: buf

    apic = ic%transfer == TRANSFER_APIC
    call grid_box(g, xmin, xmax, closed)
    vmax = 0.0_wp
    bad = 0
    associate (mc => ic%mc)
      !$omp parallel do schedule(dynamic, 1) default(shared) reduction(max:vmax) &
      !$omp private(c, lo, hi, ip, a, k, nclamp, i0, j0, i, j, ix, jy, vn, dv, vc, cu, cv, w, gxk, gyk, xo, ke, mom, wg, wb, &
      !$omp mp, s, pp, wx, wy, wc)
      do c = 1, NCHUNK
        call chunk_range(c, p%n, lo, hi)
        ke = 0.0_wp
        mom = 0.0_wp
        wg = 0.0_wp
        wb = 0.0_wp
        wc = 0.0_wp
        nclamp = 0
        do ip = lo, hi
          if (ic%coupled) then   ! the solids move with their nodes (cpdi_fsi) or as one body
            if (ic%solid(p%mat(ip)) .or. ic%rigid(p%mat(ip)) .or. ic%free(p%mat(ip))) cycle
          end if
          mp = p%m(ip)
          xo = p%x(:, ip)
          if (ic%sep) then
            call gather_sep(ic%gu, p%x(:, ip), p%r(:, ip), mc%u, mc%uc, mc%uo, vn(1), vc(1), dv(1), cu)
            call gather_sep(ic%gv, p%x(:, ip), p%r(:, ip), mc%v, mc%vc, mc%vo, vn(2), vc(2), dv(2), cv)
          else
            call gather(ic%shu, ip, mc%u, mc%uc, mc%uo, vn(1), vc(1), dv(1), cu)
            call gather(ic%shv, ip, mc%v, mc%vc, mc%vo, vn(2), vc(2), dv(2), cv)
          end if
          if (apic) then
            p%v(:, ip) = vn
          else
            p%v(:, ip) = flip*(p%v(:, ip) + dv) + (1.0_wp - flip)*vn
          end if
          p%L(:, ip) = [cu(1), cv(1), cu(2), cv(2)]
          p%x(:, ip) = xo + dt*(vn + vc)
          call hold_on_walls(p%x(:, ip), xmin, xmax, closed, nclamp)
          ! pressure: bilinear over the cell centres, extrapolated linearly across the domain's
          ! edges (a hydrostatic pressure is then exact up to the floor)
          s = (p%x(:, ip) - g%gorig)/g%h - 0.5_wp
          i0 = int(floor(s(1))) + 1
          j0 = int(floor(s(2))) + 1
          s = s - floor(s)
          call edge_weights(i0, s(1), mc%lo(1), mc%hi(1), ix, wx)
          call edge_weights(j0, s(2), mc%lo(2), mc%hi(2), jy, wy)
          pp = 0.0_wp
          do j = 1, 2
            do i = 1, 2
              k = ix(i) + (jy(j) - 1)*mc%nn(1)
              pp = pp + wx(i)*wy(j)*mc%pe(k)
            end do
          end do
          p%sig(:, ip) = [-pp, -pp, 0.0_wp, -pp]
          if (.not. (abs(p%v(1, ip)) + abs(p%v(2, ip)) + abs(pp) < huge(1.0_wp))) then
            if (bad(c) == 0) bad(c) = ip
          end if
          vmax = max(vmax, abs(p%v(1, ip)), abs(p%v(2, ip)), abs(vn(1)), abs(vn(2)))
          ke = ke + 0.5_wp*mp*(p%v(1, ip)**2 + p%v(2, ip)**2)
          mom = mom + mp*p%v(:, ip)
          wg = wg + mp*dot_product(gravity, p%x(:, ip) - xo - dt*vc)   ! the flow's part only
          wc = wc + mp*dt*dot_product(gravity, vc)
          wb = wb + mp*dot_product(p%bf(:, ip), p%x(:, ip) - xo)
        end do
        ic%red(:, c) = [ke, mom(1), mom(2), wg, wb, real(nclamp, wp), wc, 0.0_wp]
      end do
      !$omp end parallel do
    end associate
    do c = 1, NCHUNK
      if (bad(c) == 0) cycle
      write (buf, '(a,i0,a,i0,a)') 'step ', steps + 1, ': NaN or Inf in the velocity or pressure of particle ', &
        bad(c), '; the run became unstable (reduce cfl)'
      call st%set(CPDI_ERR_NAN, trim(buf))
      return
    end do
    diag(DIAG_KINETIC) = sum(ic%red(1, :))
    diag(DIAG_STRAIN) = 0.0_wp
    diag(DIAG_MOMENTUM_X) = sum(ic%red(2, :))
    diag(DIAG_MOMENTUM_Y) = sum(ic%red(3, :))
    diag(DIAG_GRAVITY_WORK) = diag(DIAG_GRAVITY_WORK) + sum(ic%red(4, :))
    diag(DIAG_BODY_FORCE_WORK) = diag(DIAG_BODY_FORCE_WORK) + sum(ic%red(5, :))
    diag(DIAG_WALL_CLAMPS) = sum(ic%red(6, :))
    diag(DIAG_CORRECTION_WORK) = diag(DIAG_CORRECTION_WORK) + sum(ic%red(7, :))
    smax = sqrt(2.0_wp)*vmax + sqrt(norm2(gravity)*g%h)
  end subroutine g2p_faces

  pure subroutine incomp_fill_weights(mc, g, x, k, w)
    !! The four cells a particle at x spreads its volume over (the cell fill: bilinear over the
    !! cell centres, indices clamped to the physical cells, a wall mirroring the water beyond it)
    !! and their weights.
    type(mac_t), intent(in) :: mc
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik), intent(out) :: k(4)
    real(wp), intent(out) :: w(4)
    integer(ik) :: i0, j0, i, j
    real(wp) :: f(2), wx(2), wy(2)
    f = (x - g%gorig)/g%h - 0.5_wp
    i0 = int(floor(f(1))) + 1
    j0 = int(floor(f(2))) + 1
    f = f - floor(f)
    wx = [1.0_wp - f(1), f(1)]
    wy = [1.0_wp - f(2), f(2)]
    do j = 0, 1
      do i = 0, 1
        k(1 + i + 2*j) = min(max(i0 + i, mc%lo(1)), mc%hi(1)) + (min(max(j0 + j, mc%lo(2)), mc%hi(2)) - 1)*mc%nn(1)
        w(1 + i + 2*j) = wx(i + 1)*wy(j + 1)
      end do
    end do
  end subroutine incomp_fill_weights

  real(wp) function incomp_pressure_at(ic, g, x) result(pp)
    !! The last projection's pressure (with its ghost values, pe) at x, interpolated as a water
    !! particle's is (g2p_faces).
    type(incomp_t), intent(in) :: ic
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik) :: i0, j0, i, j, ix(2), jy(2)
    real(wp) :: s(2), wx(2), wy(2)
    s = (x - g%gorig)/g%h - 0.5_wp
    i0 = int(floor(s(1))) + 1
    j0 = int(floor(s(2))) + 1
    s = s - floor(s)
    call edge_weights(i0, s(1), ic%mc%lo(1), ic%mc%hi(1), ix, wx)
    call edge_weights(j0, s(2), ic%mc%lo(2), ic%mc%hi(2), jy, wy)
    pp = 0.0_wp
    do j = 1, 2
      do i = 1, 2
        pp = pp + wx(i)*wy(j)*ic%mc%pe(ix(i) + (jy(j) - 1)*ic%mc%nn(1))
      end do
    end do
  end function incomp_pressure_at

  pure subroutine edge_weights(i0, f, lo, hi, idx, w)
    !! Linear interpolation between cell centres i0 and i0 + 1 at fraction f along one axis,
    !! as two (index, weight) pairs inside lo..hi: a centre beyond an edge is the linear
    !! extrapolation of the two inside it (2 p(lo) - p(lo + 1)); far outside, the edge value.
    integer(ik), intent(in) :: i0, lo, hi
    real(wp), intent(in) :: f
    integer(ik), intent(out) :: idx(2)
    real(wp), intent(out) :: w(2)
    if (i0 >= lo .and. i0 + 1 <= hi) then
      idx = [i0, i0 + 1]
      w = [1.0_wp - f, f]
    else if (i0 == lo - 1 .and. hi > lo) then
      idx = [lo, lo + 1]
      w = [2.0_wp*(1.0_wp - f) + f, -(1.0_wp - f)]
    else if (i0 == hi .and. hi > lo) then
      idx = [hi, hi - 1]
      w = [(1.0_wp - f) + 2.0_wp*f, -f]
    else
      idx = min(max(i0, lo), hi)
      w = [1.0_wp, 0.0_wp]
    end if
  end subroutine edge_weights

  pure subroutine gather(sh, ip, fv, fc, fd, vn, vc, dv, grad)
    !! One velocity component at particle ip from its face lattice: velocity vn, correction
    !! velocity vc, FLIP increment dv (from fv, fc, fd) and the component's gradient, slot by
    !! slot in shape_slot's order (face_slot).
    type(shape_t), intent(in) :: sh
    integer(ik), intent(in) :: ip
    real(wp), intent(in) :: fv(:), fc(:), fd(:)
    real(wp), intent(out) :: vn, vc, dv, grad(2)
    integer(ik) :: a, k
    real(wp) :: w, gxk, gyk
    logical :: ok
    vn = 0.0_wp
    vc = 0.0_wp
    dv = 0.0_wp
    grad = 0.0_wp
    do a = 1, sh%ns
      call face_slot(sh, ip, a, k, w, gxk, gyk, ok)
      if (.not. ok) exit
      vn = vn + w*fv(k)
      vc = vc + w*fc(k)
      dv = dv + w*fd(k)
      grad(1) = grad(1) + fv(k)*gxk
      grad(2) = grad(2) + fv(k)*gyk
    end do
  end subroutine gather

  pure subroutine gather_sep(gl, x, r, fv, fc, fd, vn, vc, dv, grad)
    !! gather with the separable weights (ic%sep) of the particle at x with domain r on lattice
    !! gl: each of the three face rows summed along x first, then weighted by its y factor.
    type(grid_t), intent(in) :: gl
    real(wp), intent(in) :: x(2), r(4), fv(:), fc(:), fd(:)
    real(wp), intent(out) :: vn, vc, dv, grad(2)
    integer(ik) :: a, b, k, i0, j0
    real(wp) :: rh, sx(3), dx(3), sy(3), dy(3), rv, rc, rd, rg
    rh = 1.0_wp/gl%h
    call sep_axis(x(1), r(1), gl%gorig(1), rh, i0, sx, dx)
    call sep_axis(x(2), r(4), gl%gorig(2), rh, j0, sy, dy)
    vn = 0.0_wp
    vc = 0.0_wp
    dv = 0.0_wp
    grad = 0.0_wp
    do b = 1, 3
      rv = 0.0_wp
      rc = 0.0_wp
      rd = 0.0_wp
      rg = 0.0_wp
      do a = 1, 3
        k = i0 + a + (j0 + b - 1)*gl%nn(1)
        rv = rv + sx(a)*fv(k)
        rc = rc + sx(a)*fc(k)
        rd = rd + sx(a)*fd(k)
        rg = rg + dx(a)*fv(k)
      end do
      vn = vn + sy(b)*rv
      vc = vc + sy(b)*rc
      dv = dv + sy(b)*rd
      grad(1) = grad(1) + sy(b)*rg
      grad(2) = grad(2) + dy(b)*rv
    end do
  end subroutine gather_sep

  subroutine incomp_transfer_cycle(ic, g, p, st)
    !! P2G to the face lattices and straight back (no forces, no projection, dt = 0; PIC,
    !! or APIC with transfer = apic): the transfer alone, for tests of what it conserves.
    type(incomp_t), intent(inout) :: ic
    type(grid_t), intent(in) :: g
    type(particles_t), intent(inout) :: p
    type(status_t), intent(inout) :: st
    real(wp) :: diag(NDIAG), smax
    integer(int64), parameter :: zero = 0
    call weights(ic, p, zero, st)
    if (.not. st%ok()) return
    call p2g_faces(ic, p, g, 0.0_wp, [0.0_wp, 0.0_wp], ic%transfer == TRANSFER_APIC)
    call face_velocities(ic%mc, 1.0e-12_wp*minval(p%m))
    ic%mc%uo = 0.0_wp
    ic%mc%vo = 0.0_wp
    ic%mc%uc = 0.0_wp
    ic%mc%vc = 0.0_wp
    diag = 0.0_wp
    call g2p_faces(ic, g, p, 0.0_wp, 0.0_wp, [0.0_wp, 0.0_wp], diag, smax, st, zero)
  end subroutine incomp_transfer_cycle

  subroutine tic(t0)
    integer(int64), intent(out) :: t0
    call system_clock(t0)
  end subroutine tic

  subroutine toc(timers, slot, t0)
    real(wp), intent(inout) :: timers(:)
    integer(ik), intent(in) :: slot
    integer(int64), intent(inout) :: t0
    integer(int64) :: t1, rate
    call system_clock(t1, rate)
    timers(slot) = timers(slot) + real(t1 - t0, wp)/real(rate, wp)
    t0 = t1
  end subroutine toc
end module cpdi_incompressible
