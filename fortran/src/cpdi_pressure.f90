!> Pressure projection of incompressible water on a staggered (MAC) grid.
module cpdi_pressure
  !! Cells are those of the background grid: pressure at cell centres, the x velocity u on
  !! vertical faces and the y velocity v on horizontal faces (Harlow & Welch 1965). All arrays
  !! use the padded node numbering of cpdi_grid: cell k is the cell whose lower-left node is
  !! node k, u(k) is its left face and v(k) its bottom face, so the u lattice is the node
  !! lattice shifted by h/2 in y and the v lattice the node lattice shifted by h/2 in x.
  !!
  !! The discrete divergence (cells) and gradient (faces) are adjoint, so the Laplacian is
  !! the 5-point stencil: it has no checkerboard null mode (docs/incompressible_water.md).
  !!
  !! * Cells hold water (CELL_FLUID: a water particle's centre lies in them, or the level set or
  !!   the fill says so: cpdi_incompressible p2g_faces), air
  !!   (CELL_AIR: p = 0) or a wall (CELL_SOLID: beyond a closed wall; the face to it carries
  !!   the wall's zero normal velocity, a Neumann condition for p).
  !! * Free surface, ghost fluid (Gibou et al. 2002): the surface lies at theta h from a water
  !!   cell's centre towards an air neighbour; the air side's pressure is the ghost value
  !!   p_c (1 - 1/theta), so p = 0 on the surface itself (mac_theta). Water alone (levelset):
  !!   where the level set of mac_level_set (a signed distance from the smoothed cell fill)
  !!   changes sign between the two centres. With solids coupled: where the cell fill fraction
  !!   (particle volume per cell area, spread bilinearly) falls through 1/2.
  !! * Volume correction (after Kugelstadt et al. 2019): a water cell filled beyond 1 gets
  !!   a divergence target q = beta (fill - 1) / dt, so over-packed water spreads again. It
  !!   is solved for on its own (cpdi_incompressible): its velocity moves the particles but is
  !!   not kept in their momentum, so it adds no force to the flow.
  !! * Solve: conjugate gradients from p = 0 (a step depends on the particles alone, so a
  !!   restart from a checkpoint is exact); relative residual ||b - A p||_2 / ||b||_2 <= tol.
  !!   Preconditioned (precond) by modified incomplete Cholesky, MIC(0) (Bridson 2015, ch. 5;
  !!   iterations grow like sqrt(cells)), or by one geometric multigrid V-cycle (cpdi_multigrid;
  !!   iterations about constant in the grid size).
  !! * Closed water (issue 38): a water region (connected through A's couplings) whose rows sum to
  !!   zero, with no free body's low-rank term, has the constant in A's null space: p defined up to
  !!   a constant and A p = b is solvable only if b sums to zero over it. The solve finds these
  !!   regions, removes each one's mean from b (the removed part, relative to ||b||, is `defect`:
  !!   round-off for a physical step, the unreachable part of a target such as a uniform volume
  !!   correction otherwise), keeps the preconditioned residuals free of the constants, and
  !!   fixes each region's constant so that the pressure, extrapolated linearly to the top faces of
  !!   its highest row, is zero there on average: a tank filled to the lid and closed at zero gauge
  !!   pressure, the level an open tank filled to the same height has at its surface.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC, CPDI_ERR_STATE
  use cpdi_options, only: optset_t, opt_value
  use cpdi_multigrid, only: mg_t, mg_alloc, mg_build, mg_apply
  implicit none
  private

  integer(ik), parameter, public :: CELL_AIR = 0
  integer(ik), parameter, public :: CELL_FLUID = 1
  integer(ik), parameter, public :: CELL_SOLID = 2
  integer(ik), parameter, public :: FACE_WATER = 1   !! uval, vval: a face the projection set from the water's pressure
  integer(ik), parameter, public :: FACE_WALL = -1   !! uval, vval: a wall's (or body's) face: its normal velocity
  integer, parameter :: LVL_PASSES = 1        !! mac_level_set: binomial passes over the fill
  real(wp), parameter :: LVL_MAX = 1.0_wp + LVL_PASSES   !! mac_level_set: |distance| it resolves [h] (the smoothed fill's reach)
  real(wp), parameter, public :: LVL_WATER = -1.0e-6_wp  !! mac_level_set: a cell centre below this distance is water [h]
  real(wp), parameter :: MIC_TAU = 0.97_wp    !! MIC(0) modification (Bridson 2015)
  real(wp), parameter :: MIC_SIGMA = 0.25_wp  !! MIC(0) safety: fall back to the diagonal below this
  real(wp), parameter :: ANCHOR = 1.0e-10_wp   !! a row of A anchors its region if it sums to more than this of its diagonal
  integer(ik), parameter, public :: PRECOND_MIC0 = 0       !! MIC(0): incomplete Cholesky
  integer(ik), parameter, public :: PRECOND_MULTIGRID = 1  !! one geometric multigrid V-cycle
  integer(ik), parameter :: CG_PAR_MIN = 8192            !! physical cells above which the CG's row loops are threaded

  type, public :: mac_t
    !! Staggered-grid fields over the padded node numbering (one entry per node index).
    integer(ik) :: nn(2) = 0                 !! lattice size (= the nodal grid's, padding included)
    integer(ik) :: lo(2) = 0, hi(2) = 0      !! physical cells: lattice indices lo..hi per axis
    real(wp) :: h = 0.0_wp                   !! cell size [m]
    integer(ik), allocatable :: cell(:)      !! CELL_AIR, CELL_FLUID or CELL_SOLID
    real(wp), allocatable :: fill(:)         !! cell fill fraction [-]
    logical :: levelset = .false.            !! the surface from lvl (mac_level_set), not from fill
    real(wp), allocatable :: lvl(:)          !! levelset: signed distance to the surface, in cells (< 0: water)
    real(wp), allocatable :: lvt(:)          !! levelset: work (the smoothed fill)
    real(wp), allocatable :: um(:), vm(:)    !! face masses
    real(wp), allocatable :: u(:), v(:)      !! face velocities (momenta during P2G)
    real(wp), allocatable :: uo(:), vo(:)    !! face velocities before forces and projection
    real(wp), allocatable :: uc(:), vc(:)    !! volume-correction velocities (advection only)
    integer(ik), allocatable :: uval(:), vval(:) !! FACE_WATER, FACE_WALL: set by the projection; 0: not set
    real(wp), allocatable :: p(:)            !! cell pressure [Pa]
    real(wp), allocatable :: pe(:)           !! pressure with ghost values in air cells next to water
    real(wp), allocatable :: b(:), adiag(:), ai(:), aj(:), pre(:), r(:), z(:), s(:), q(:)
    real(wp), allocatable :: ua(:), va(:)    !! face coefficients rho_w / rho_face (1 on water faces)
    real(wp), allocatable :: rvx(:), rvy(:)  !! velocity of a CELL_SOLID cell (0: wall; a rigid body's)
    integer(ik) :: nfluid = 0                !! water cells
    integer(ik), allocatable :: slo(:), shi(:) !! per row j: first and last water cell (slo > shi: none), set by each solve
    ! A low-rank term of the matrix (free rigid bodies, cpdi_rigid_body): A += sum_b J_b D_b J_b^T,
    ! J_b the body's 3 columns (x, y velocity, rotation) over the cells it bounds, D_b = rho M_b^-1.
    integer(ik) :: nlr = 0                   !! entries of the term (0: none)
    integer(ik), allocatable :: lrc(:)       !! entry e: its cell
    integer(ik), allocatable :: lrb(:)       !! entry e: its body
    real(wp), allocatable :: lrj(:, :)       !! entry e: J of its cell (3)
    real(wp), allocatable :: lrd(:, :)       !! per body: D's diagonal (3)
    integer(ik) :: iters = 0                 !! CG iterations of the last solve
    real(wp) :: resid = 0.0_wp               !! relative residual of the last solve
    integer(ik) :: precond = PRECOND_MIC0    !! the CG's preconditioner
    type(mg_t) :: mg                         !! the multigrid levels (PRECOND_MULTIGRID)
    type(optset_t) :: ov                     !! the simulation's options (cpdi_sim sim_apply_options copies them):
                                             !! the pressure stages read theirs by name, opt_value(mc%ov, 'name')
    ! Closed water regions (no air: the constant is in A's null space), found by each solve.
    integer(ik) :: nfloat = 0                !! closed regions of the last solve
    real(wp) :: defect = 0.0_wp              !! ||b's part in the null space||_2 / ||b||_2 of the last solve
    integer(ik), allocatable :: rgn(:)       !! per cell: its closed region (0: none)
    integer(ik), allocatable :: stk(:)       !! flood-fill stack
    integer(ik), allocatable :: lev(:)       !! mac_extrapolate: each face's layer (work)
    integer(ik), allocatable :: elo(:), ehi(:) !! mac_extrapolate: per lattice row, first and last water face (work)
    integer(ik), allocatable :: rlab(:)      !! per region found: its closed region or 0; then a closed region's top row
    integer(ik), allocatable :: rcnt(:)      !! per closed region: cells
    real(wp), allocatable :: rsum(:)         !! per closed region: a sum
  end type mac_t

  public :: mac_precondition
  public :: mac_level_set, mac_theta
  public :: mac_alloc, mac_clear_system, mac_mark_outside, surface_theta, mac_walls, mac_assemble, mac_solve, mac_project, &
            mac_extrapolate, mac_constrain, mac_ghost_pressure, mac_apply

contains

  subroutine mac_alloc(mc, nn, lo, hi, h, st)
    !! Storage for a lattice of nn(1) x nn(2) entries, physical cells lo..hi.
    type(mac_t), intent(inout) :: mc
    integer(ik), intent(in) :: nn(2), lo(2), hi(2)
    real(wp), intent(in) :: h
    type(status_t), intent(inout) :: st
    integer :: ierr, n
    n = nn(1)*nn(2)
    if (allocated(mc%cell)) deallocate (mc%cell, mc%fill, mc%lvl, mc%lvt, &
                                        mc%um, mc%vm, mc%u, mc%v, mc%uo, mc%vo, mc%uc, mc%vc, &
                                        mc%uval, mc%vval, mc%p, mc%pe, mc%b, mc%adiag, mc%ai, mc%aj, mc%pre, mc%r, mc%z, &
                                        mc%s, mc%q, mc%ua, mc%va, mc%rvx, mc%rvy, mc%rgn, mc%stk, mc%rlab, mc%rcnt, &
                                        mc%rsum, mc%slo, mc%shi, mc%lev, mc%elo, mc%ehi)
    allocate (mc%slo(nn(2)), mc%shi(nn(2)), mc%lev(n), mc%elo(nn(2)), mc%ehi(nn(2)), &
              mc%cell(n), mc%fill(n), mc%lvl(n), mc%lvt(n), &
              mc%um(n), mc%vm(n), mc%u(n), mc%v(n), mc%uo(n), mc%vo(n), mc%uc(n), mc%vc(n), mc%uval(n), &
              mc%vval(n), mc%p(n), mc%pe(n), mc%b(n), mc%adiag(n), mc%ai(n), mc%aj(n), mc%pre(n), mc%r(n), &
              mc%z(n), mc%s(n), mc%q(n), mc%ua(n), mc%va(n), mc%rvx(n), mc%rvy(n), mc%rgn(n), mc%stk(n), mc%rlab(n), &
              mc%rcnt(n), mc%rsum(n), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the pressure grid; use a larger cell size')
      return
    end if
    call mg_alloc(mc%mg, hi(1) - lo(1) + 1, hi(2) - lo(2) + 1, st)
    if (.not. st%ok()) return
    mc%nn = nn
    mc%lo = lo
    mc%hi = hi
    mc%h = h
    mc%cell = CELL_AIR
    mc%fill = 0.0_wp
    mc%lvl = LVL_MAX
    mc%lvt = 0.0_wp
    mc%um = 0.0_wp
    mc%vm = 0.0_wp
    mc%u = 0.0_wp
    mc%v = 0.0_wp
    mc%uo = 0.0_wp
    mc%vo = 0.0_wp
    mc%uc = 0.0_wp
    mc%vc = 0.0_wp
    mc%uval = 0
    mc%vval = 0
    mc%p = 0.0_wp
    mc%pe = 0.0_wp
    mc%b = 0.0_wp
    mc%adiag = 0.0_wp
    mc%ai = 0.0_wp
    mc%aj = 0.0_wp
    mc%pre = 0.0_wp
    mc%r = 0.0_wp
    mc%z = 0.0_wp
    mc%s = 0.0_wp
    mc%q = 0.0_wp
    mc%ua = 1.0_wp
    mc%va = 1.0_wp
    mc%rvx = 0.0_wp
    mc%rvy = 0.0_wp
    mc%rgn = 0
    mc%stk = 0
    mc%lev = 0
    mc%elo = 0
    mc%ehi = 0
    mc%rlab = 0
    mc%rcnt = 0
    mc%rsum = 0.0_wp
    mc%nfloat = 0
    mc%defect = 0.0_wp
  end subroutine mac_alloc

  subroutine mac_mark_outside(mc, closed)
    !! Cells outside the physical domain: CELL_SOLID beyond a closed wall, CELL_AIR beyond an
    !! open side; physical cells become CELL_AIR (the transfer marks the water cells).
    type(mac_t), intent(inout) :: mc
    logical, intent(in) :: closed(4)   !! left, right, bottom, top
    integer(ik) :: i, j, k
    logical :: solid
    do j = 1, mc%nn(2)
      do i = 1, mc%nn(1)
        k = i + (j - 1)*mc%nn(1)
        solid = (i < mc%lo(1) .and. closed(1)) .or. (i > mc%hi(1) .and. closed(2)) .or. &
                (j < mc%lo(2) .and. closed(3)) .or. (j > mc%hi(2) .and. closed(4))
        mc%cell(k) = merge(CELL_SOLID, CELL_AIR, solid)
      end do
    end do
  end subroutine mac_mark_outside

  subroutine mac_walls(mc)
    !! Faces between a wall cell and any other cell get the wall's normal velocity: zero for
    !! the domain's walls, the body's for a rigid body's cells (rvx, rvy), before the pressure
    !! equation is assembled: its right-hand side sees them.
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, k, n1
    n1 = mc%nn(1)
    do j = 2, mc%nn(2)
      do i = 2, n1
        k = i + (j - 1)*n1
        if ((mc%cell(k - 1) == CELL_SOLID) .neqv. (mc%cell(k) == CELL_SOLID)) &
          mc%u(k) = merge(mc%rvx(k - 1), mc%rvx(k), mc%cell(k - 1) == CELL_SOLID)
        if ((mc%cell(k - n1) == CELL_SOLID) .neqv. (mc%cell(k) == CELL_SOLID)) &
          mc%v(k) = merge(mc%rvy(k - n1), mc%rvy(k), mc%cell(k - n1) == CELL_SOLID)
      end do
    end do
  end subroutine mac_walls

  pure real(wp) function surface_theta(mc, fw, fa)
    !! Distance, in cells, from a water cell's centre (fill fw) to the surface towards an air
    !! neighbour (fill fa): where the linear fill between the two centres is 1/2.
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: fw, fa
    if (fw <= 0.5_wp) then
      surface_theta = opt_value(mc%ov, 'theta_min')
    else if (fa >= 0.5_wp) then
      surface_theta = 1.0_wp
    else
      surface_theta = min(1.0_wp, max(opt_value(mc%ov, 'theta_min'), (fw - 0.5_wp)/(fw - fa)))
    end if
  end function surface_theta

  pure real(wp) function mac_theta(mc, cw, ca)
    !! Distance, in cells, from water cell cw's centre to the surface towards its air neighbour ca:
    !! from the level set where the cell of the surface is mac_level_set's (levelset), from the cell
    !! fill (surface_theta) otherwise. A water cell whose centre the level set puts outside the
    !! water (spray, thin sheets: water by its particle's centre alone) has the surface at the option theta_min.
    type(mac_t), intent(in) :: mc
    integer(ik), intent(in) :: cw, ca
    real(wp) :: lw, la
    if (.not. mc%levelset) then
      mac_theta = surface_theta(mc, mc%fill(cw), mc%fill(ca))
      return
    end if
    lw = mc%lvl(cw)
    la = mc%lvl(ca)
    if (lw >= LVL_WATER) then
      mac_theta = opt_value(mc%ov, 'theta_min')
    else if (la < 0.0_wp) then
      mac_theta = 1.0_wp
    else
      mac_theta = min(1.0_wp, max(opt_value(mc%ov, 'theta_min'), lw/(lw - la)))
    end if
  end function mac_theta

  subroutine mac_level_set(mc)
    !! lvl: the water's signed distance from the cell centres, in cells (< 0 in the water), from the
    !! cell fill. The fill (particle volume spread bilinearly over the cell centres) is smoothed once
    !! more by the binomial filter (1/4, 1/2, 1/4) along each axis. Beyond an open edge the fill is
    !! extrapolated linearly, within [0, 1] (exact for a flat surface on the edge cell's lower face
    !! or on the open edge itself). Beyond a closed wall: where the water lies along the wall (its
    !! fill changes faster across the wall's normal than along the wall: the bottom under a
    !! surface, a film) the water is mirrored, as in the fill; where a surface meets the wall, the
    !! fill is extrapolated linearly (within [0, 1]), so that a tilted surface continues straight
    !! into a slip wall: the mirror made a kink of it at the wall (accelerated_tank: the water next
    !! to the walls moved most once the particles' staircase was fine; docs/notes/accelerated_tank.md).
    !! For a flat surface meeting a wall the two agree. Each cell's smoothed fill f is turned into the distance d at
    !! which a half-plane of water, seen through the same two filters, fills a cell to f:
    !! F(d) = sum_k w_k T(d + k), k = -1, 0, 1, with T(d) the bilinear fill of a cell whose centre
    !! lies d cells above a flat surface ((1 - d)^2 / 2 for 0 <= d <= 1, 1 - (1 + d)^2 / 2 for
    !! -1 <= d <= 0). For a flat surface the distance is exact (the midpoint sums of the particles
    !! on their lattice are the filters' integrals); for a tilted plane nearly so, and linear
    !! interpolation of lvl between two cell centres then places the plane where it is along both
    !! axes: the ghost-fluid pressure of water at rest under gravity and a uniform body force is
    !! hydrostatic along both (with the plane's exact distance, accelerated_tank rests to
    !! round-off). The particles' staircase along a tilted surface (their tops step by one particle
    !! spacing) is smoothed over about 4 cells, to a plane within about 0.02 h at slope 0.2: the
    !! fill's 1/2 crossing (bilinear, 2 cells) followed the steps, within about 0.1 h, and its
    !! pressure errors along the surface moved the water (docs/notes/accelerated_tank.md). More
    !! passes (LVL_PASSES 2, 3) measured worse there. Cells out of the physical range keep LVL_MAX
    !! (air).
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1, a
    integer :: pass
    real(wp), parameter :: w(-1:1) = [0.25_wp, 0.5_wp, 0.25_wp]
    n1 = mc%nn(1)
    ! the cell loops are element-wise (threaded: the same bits at any thread count); ghost_ring is serial
    !$omp parallel do schedule(static) private(i, c)
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        mc%lvl(c) = mc%fill(c)
      end do
    end do
    !$omp end parallel do
    do pass = 1, LVL_PASSES
      call ghost_ring()
      !$omp parallel do schedule(static) private(i, c)
      do j = mc%lo(2) - 1, mc%hi(2) + 1   ! along x into lvt, the ghost rows too
        do i = mc%lo(1), mc%hi(1)
          c = i + (j - 1)*n1
          mc%lvt(c) = w(-1)*mc%lvl(c - 1) + w(0)*mc%lvl(c) + w(1)*mc%lvl(c + 1)
        end do
      end do
      !$omp end parallel do
      !$omp parallel do schedule(static) private(i, c)
      do j = mc%lo(2), mc%hi(2)   ! along y back into lvl
        do i = mc%lo(1), mc%hi(1)
          c = i + (j - 1)*n1
          mc%lvl(c) = w(-1)*mc%lvt(c - n1) + w(0)*mc%lvt(c) + w(1)*mc%lvt(c + n1)
        end do
      end do
      !$omp end parallel do
    end do
    do j = mc%lo(2) - 1, mc%hi(2) + 1   ! the ring back to air
      mc%lvl(mc%lo(1) - 1 + (j - 1)*n1) = LVL_MAX
      mc%lvl(mc%hi(1) + 1 + (j - 1)*n1) = LVL_MAX
    end do
    do i = mc%lo(1), mc%hi(1)
      mc%lvl(i + (mc%lo(2) - 2)*n1) = LVL_MAX
      mc%lvl(i + mc%hi(2)*n1) = LVL_MAX
    end do
    !$omp parallel do schedule(dynamic, 4) private(i, c)   ! dynamic: only the surface's rows cost
    do j = mc%lo(2), mc%hi(2)   ! the smoothed fill to the distance
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        mc%lvl(c) = fill_distance(mc%lvl(c))
      end do
    end do
    !$omp end parallel do
  contains
    subroutine ghost_ring()
      !! The fill one cell beyond each edge (lvl's ring), set before the two passes so that the
      !! filter is one linear 3 x 3 filter whatever the order of the axes: beyond an open edge the
      !! fill extrapolated linearly (within [0, 1]); beyond a wall mirrored where the water lies
      !! along it (along_wall), else extrapolated; beyond the edge of a single row or column its own
      !! fill. A corner: the mean of its two neighbours in the ring.
      integer(ik) :: e, k, ki, kg, lo1, hi1, lo2, hi2
      lo1 = mc%lo(1); hi1 = mc%hi(1); lo2 = mc%lo(2); hi2 = mc%hi(2)
      do j = lo2, hi2
        do e = -1, 1, 2
          k = merge(lo1, hi1, e < 0) + (j - 1)*n1
          kg = k + e
          ki = k - e
          mc%lvl(kg) = ghost(k, ki, kg, merge(k, k - n1, j == lo2), merge(k, k + n1, j == hi2), lo1 == hi1)
        end do
      end do
      do i = lo1, hi1
        do e = -1, 1, 2
          k = i + (merge(lo2, hi2, e < 0) - 1)*n1
          kg = k + e*n1
          ki = k - e*n1
          mc%lvl(kg) = ghost(k, ki, kg, merge(k, k - 1, i == lo1), merge(k, k + 1, i == hi1), lo2 == hi2)
        end do
      end do
      do e = -1, 1, 2   ! a corner: the mean of the ring row's and the ring column's rule applied to it
        do a = -1, 1, 2
          i = merge(lo1, hi1, e < 0)   ! the corner's edge cell
          j = merge(lo2, hi2, a < 0)
          k = i + (j - 1)*n1
          c = k + e + a*n1
          mc%lvl(c) = 0.5_wp*(ghost_from(c - e, c - 2*e, mirrors(k, k - e, k + e, merge(k, k - n1, j == lo2), &
                                                                 merge(k, k + n1, j == hi2), lo1 == hi1)) &
                              + ghost_from(c - a*n1, c - 2*a*n1, mirrors(k, k - a*n1, k + a*n1, merge(k, k - 1, i == lo1), &
                                                                         merge(k, k + 1, i == hi1), lo2 == hi2)))
        end do
      end do
    end subroutine ghost_ring

    real(wp) function ghost(k, ki, kg, kt1, kt2, single)
      !! The ring's fill beyond edge cell k (ki: the next cell inward, kg: the ring cell, kt1 and
      !! kt2: the edge cells on either side of k along the edge).
      integer(ik), intent(in) :: k, ki, kg, kt1, kt2
      logical, intent(in) :: single
      ghost = ghost_from(k, ki, mirrors(k, ki, kg, kt1, kt2, single))
    end function ghost

    real(wp) function ghost_from(k, ki, mirror)
      !! The value beyond k: k's own (mirror) or extrapolated linearly from ki through k, in [0, 1].
      integer(ik), intent(in) :: k, ki
      logical, intent(in) :: mirror
      if (mirror) then
        ghost_from = mc%lvl(k)
      else
        ghost_from = min(1.0_wp, max(0.0_wp, 2.0_wp*mc%lvl(k) - mc%lvl(ki)))
      end if
    end function ghost_from

    logical function mirrors(k, ki, kg, kt1, kt2, single)
      !! Whether the ring cell kg beyond edge cell k takes k's own fill: beyond the edge of a single
      !! row or column, or beyond a wall the water lies along (along_wall).
      integer(ik), intent(in) :: k, ki, kg, kt1, kt2
      logical, intent(in) :: single
      mirrors = single
      if (.not. mirrors) mirrors = mc%cell(kg) == CELL_SOLID
      if (mirrors .and. .not. single) mirrors = along_wall(k, ki, kt1, kt2)
    end function mirrors

    pure logical function along_wall(ke, ki, kt1, kt2)
      !! Whether the water next to a wall lies along it (its fill, mc%fill, changes more from the
      !! edge cell ke to the cell ki inward than along the wall from kt1 to kt2, over two cells):
      !! then the wall mirrors it, else (a surface meeting the wall) the fill continues straight.
      !! Decided on the unsmoothed fill, so that both passes and an exchange of the axes agree.
      integer(ik), intent(in) :: ke, ki, kt1, kt2
      along_wall = abs(mc%fill(ke) - mc%fill(ki)) > 0.5_wp*abs(mc%fill(kt2) - mc%fill(kt1))
    end function along_wall
  end subroutine mac_level_set

  pure real(wp) function fill_distance(f) result(d)
    !! The d in [-LVL_MAX, LVL_MAX] with F(d) = f (mac_level_set's F, decreasing from 1 to 0):
    !! bisection to round-off.
    real(wp), intent(in) :: f
    real(wp) :: lo, hi, mid
    integer :: it
    if (f >= 1.0_wp) then
      d = -LVL_MAX
      return
    else if (f <= 0.0_wp) then
      d = LVL_MAX
      return
    end if
    lo = -LVL_MAX
    hi = LVL_MAX
    do it = 1, 60
      mid = 0.5_wp*(lo + hi)
      if (profile(mid) > f) then
        lo = mid
      else
        hi = mid
      end if
    end do
    d = 0.5_wp*(lo + hi)
  contains
    pure real(wp) function profile(x)
      !! F(x) = sum_k b_k T(x + k), b the binomial weights of LVL_PASSES passes (k = -LVL_PASSES..LVL_PASSES).
      real(wp), intent(in) :: x
      real(wp) :: b(-LVL_PASSES:LVL_PASSES), bn(-LVL_PASSES:LVL_PASSES)
      integer :: k, q
      b = 0.0_wp
      b(0) = 1.0_wp
      do q = 1, LVL_PASSES
        bn = 0.5_wp*b
        bn(-LVL_PASSES + 1:) = bn(-LVL_PASSES + 1:) + 0.25_wp*b(:LVL_PASSES - 1)
        bn(:LVL_PASSES - 1) = bn(:LVL_PASSES - 1) + 0.25_wp*b(-LVL_PASSES + 1:)
        b = bn
      end do
      profile = 0.0_wp
      do k = -LVL_PASSES, LVL_PASSES
        profile = profile + b(k)*tent_cdf(x + real(k, wp))
      end do
    end function profile
  end function fill_distance

  pure real(wp) function tent_cdf(d)
    !! Bilinear fill of a cell whose centre lies d cells above a flat water surface.
    real(wp), intent(in) :: d
    if (d >= 1.0_wp) then
      tent_cdf = 0.0_wp
    else if (d >= 0.0_wp) then
      tent_cdf = 0.5_wp*(1.0_wp - d)**2
    else if (d >= -1.0_wp) then
      tent_cdf = 1.0_wp - 0.5_wp*(1.0_wp + d)**2
    else
      tent_cdf = 1.0_wp
    end if
  end function tent_cdf

  subroutine mac_clear_system(mc)
    !! Zero the pressure system (matrix, right-hand side, preconditioner) on the cells and their
    !! ghost ring, and the pressure outside the water; the assemblies fill it again.
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1
    n1 = mc%nn(1)
    mc%nfluid = 0
    do j = mc%lo(2) - 1, mc%hi(2) + 1
      do i = mc%lo(1) - 1, mc%hi(1) + 1
        c = i + (j - 1)*n1
        mc%adiag(c) = 0.0_wp
        mc%ai(c) = 0.0_wp
        mc%aj(c) = 0.0_wp
        mc%b(c) = 0.0_wp
        mc%pre(c) = 0.0_wp
        if (mc%cell(c) /= CELL_FLUID) mc%p(c) = 0.0_wp
      end do
    end do
  end subroutine mac_clear_system

  subroutine mac_assemble(mc, dt, rho, beta, qfill)
    !! Matrix (5-point, ghost-fluid surface) and right-hand side of the pressure equation
    !! A p = (rho h^2 / dt) (q - div u) on the water cells, from the face velocities u, v.
    !! Each face enters with its coefficient ua, va = rho / rho_face (1 on water faces; a
    !! face shared with a solid has the mixture's density, cpdi_incompressible).
    !! q = beta (f - 1) / dt where f > 1, f the cell fill, or qfill when given (coupled runs:
    !! the water's own fill, so the correction never pushes water off a solid).
    !! With qfill, also under-filled cells: q = beta max(f - 1, -1/2) / dt where the cell fill
    !! f < 1 in a water cell whose four neighbours are water cells, one of them over-filled
    !! (qfill > 1): a packing error is a surplus next to a deficit, and the correction moves the
    !! surplus into the deficit instead of outward (two-sided inside the water, as Kugelstadt et
    !! al. 2019; the surface is not pulled in, uniformly sparse water is left alone). Over-filling
    !! alone ratchets: FLIP noise leaves cells above and below 1, and pushing only the former
    !! apart grew the water's volume by ~20 % in 0.5 s (elastic_obstacle, issue 21).
    !! Without qfill (water alone), likewise two-sided: q = beta max(f - 1, -1/2) / dt in an
    !! under-filled water cell with no air neighbour (its neighbours water or wall). The
    !! one-sided correction left the cells along the walls of the Lobovsky dam break at fill
    !! 0.5-0.8 (the water spread out there) and its wall pressure 20 % above the converged 2D
    !! references at 80 mm (docs/notes/dam_break_pressure_sensor4.md, issue 38). The checks'
    !! volume measure (harness.water.volume_change) counts that spreading as well as packing.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: dt, rho, beta
    real(wp), intent(in), optional :: qfill(:)
    integer(ik) :: i, j, c, n1, nb(4), a
    real(wp) :: scale, div, qv, af(4)
    n1 = mc%nn(1)
    scale = rho*mc%h**2/dt
    call mac_clear_system(mc)
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) cycle
        mc%nfluid = mc%nfluid + 1
        nb = [c - 1, c + 1, c - n1, c + n1]
        af = [mc%ua(c), mc%ua(c + 1), mc%va(c), mc%va(c + n1)]
        do a = 1, 4
          select case (mc%cell(nb(a)))
          case (CELL_FLUID)
            mc%adiag(c) = mc%adiag(c) + af(a)
            if (a == 2) mc%ai(c) = -af(a)
            if (a == 4) mc%aj(c) = -af(a)
          case (CELL_AIR)
            mc%adiag(c) = mc%adiag(c) + af(a)/mac_theta(mc, c, nb(a))
          end select
        end do
        div = (mc%u(c + 1) - mc%u(c) + mc%v(c + n1) - mc%v(c))/mc%h
        qv = 0.0_wp
        if (present(qfill)) then
          if (qfill(c) > 1.0_wp) qv = beta*(qfill(c) - 1.0_wp)/dt
          if (mc%fill(c) < 1.0_wp .and. all(mc%cell(nb) == CELL_FLUID) .and. any(qfill(nb) > 1.0_wp)) &
            qv = beta*max(mc%fill(c) - 1.0_wp, -0.5_wp)/dt
        else
          if (mc%fill(c) > 1.0_wp) qv = beta*(mc%fill(c) - 1.0_wp)/dt
          if (mc%fill(c) < 1.0_wp .and. all(mc%cell(nb) /= CELL_AIR)) &
            qv = beta*max(mc%fill(c) - 1.0_wp, -0.5_wp)/dt
        end if
        mc%b(c) = scale*(qv - div)
      end do
    end do
  end subroutine mac_assemble

  subroutine mac_apply(mc, x, y, spans)
    !! y = A x on the water cells (0 elsewhere). With spans, only each row's span of water cells
    !! (slo..shi, set by the solve) is written: y must already vanish outside them.
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: x(:)
    real(wp), intent(inout) :: y(:)
    logical, intent(in), optional :: spans
    integer(ik) :: i, j, c, n1
    logical :: sp
    n1 = mc%nn(1)
    sp = .false.
    if (present(spans)) sp = spans
    ! rows in parallel: each cell's value is computed as serially, so any thread count gives
    ! the same bits
    !$omp parallel do if (cg_parallel(mc)) default(shared) private(i, c) schedule(static)
    do j = mc%lo(2), mc%hi(2)
      do i = merge(mc%slo(j), mc%lo(1), sp), merge(mc%shi(j), mc%hi(1), sp)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) then
          y(c) = 0.0_wp
          cycle
        end if
        y(c) = mc%adiag(c)*x(c) + mc%ai(c)*x(c + 1) + mc%ai(c - 1)*x(c - 1) + mc%aj(c)*x(c + n1) &
               + mc%aj(c - n1)*x(c - n1)
      end do
    end do
    !$omp end parallel do
    if (mc%nlr > 0) call lowrank_apply(mc, x, y)
  end subroutine mac_apply

  subroutine lowrank_apply(mc, x, y)
    !! y <- y + sum_b J_b D_b J_b^T x (the free rigid bodies' rows; cells in a fixed order, so the
    !! sums do not depend on the thread count).
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: x(:)
    real(wp), intent(inout) :: y(:)
    real(wp) :: t(3, size(mc%lrd, 2))
    integer(ik) :: e
    t = 0.0_wp
    do e = 1, mc%nlr
      t(:, mc%lrb(e)) = t(:, mc%lrb(e)) + mc%lrj(:, e)*x(mc%lrc(e))
    end do
    t = t*mc%lrd
    do e = 1, mc%nlr
      y(mc%lrc(e)) = y(mc%lrc(e)) + dot_product(mc%lrj(:, e), t(:, mc%lrb(e)))
    end do
  end subroutine lowrank_apply

  subroutine mic0(mc)
    !! MIC(0) factor: pre = 1 / sqrt(e) of every water cell.
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1
    real(wp) :: e
    n1 = mc%nn(1)
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) cycle
        e = mc%adiag(c) - (mc%ai(c - 1)*mc%pre(c - 1))**2 - (mc%aj(c - n1)*mc%pre(c - n1))**2 &
            - MIC_TAU*(mc%ai(c - 1)*mc%aj(c - 1)*mc%pre(c - 1)**2 + mc%aj(c - n1)*mc%ai(c - n1)*mc%pre(c - n1)**2)
        if (e < MIC_SIGMA*mc%adiag(c)) e = mc%adiag(c)
        mc%pre(c) = 0.0_wp
        if (e > 0.0_wp) mc%pre(c) = 1.0_wp/sqrt(e)   ! a water cell walled in on all sides: no row
      end do
    end do
  end subroutine mic0

  subroutine mic0_apply(mc)
    !! z = M^-1 r with the MIC(0) factor (forward, then backward substitution); q is scratch.
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1
    real(wp) :: t
    n1 = mc%nn(1)
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) then
          mc%q(c) = 0.0_wp
          cycle
        end if
        t = mc%r(c) - mc%ai(c - 1)*mc%pre(c - 1)*mc%q(c - 1) - mc%aj(c - n1)*mc%pre(c - n1)*mc%q(c - n1)
        mc%q(c) = t*mc%pre(c)
      end do
    end do
    do j = mc%hi(2), mc%lo(2), -1
      do i = mc%hi(1), mc%lo(1), -1
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) then
          mc%z(c) = 0.0_wp
          cycle
        end if
        t = mc%q(c) - mc%ai(c)*mc%pre(c)*mc%z(c + 1) - mc%aj(c)*mc%pre(c)*mc%z(c + n1)
        mc%z(c) = t*mc%pre(c)
      end do
    end do
  end subroutine mic0_apply

  real(wp) function fdot(mc, x, y)
    !! Sum of x y over the water cells: each row's dot product over its span of water cells
    !! (slo..shi, in parallel; x y vanishes outside, so the row's serial sum is the same), then
    !! the rows in order, as the serial loop summed them.
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: x(:), y(:)
    real(wp) :: row(mc%lo(2):mc%hi(2))
    integer(ik) :: j, c0, c1
    !$omp parallel do if (cg_parallel(mc)) default(shared) private(c0, c1) schedule(static)
    do j = mc%lo(2), mc%hi(2)
      c0 = mc%slo(j) + (j - 1)*mc%nn(1)
      c1 = mc%shi(j) + (j - 1)*mc%nn(1)
      row(j) = dot_product(x(c0:c1), y(c0:c1))
    end do
    !$omp end parallel do
    fdot = 0.0_wp
    do j = mc%lo(2), mc%hi(2)
      fdot = fdot + row(j)
    end do
  end function fdot

  pure logical function cg_parallel(mc)
    !! The CG's row loops run threaded on grids of more than CG_PAR_MIN physical cells.
    type(mac_t), intent(in) :: mc
    cg_parallel = (mc%hi(1) - mc%lo(1) + 1)*(mc%hi(2) - mc%lo(2) + 1) > CG_PAR_MIN
  end function cg_parallel

  subroutine mac_solve(mc, tol, maxit, converged)
    !! Solve A p = b by preconditioned CG (mc%precond) from p = 0. Sets iters and resid;
    !! converged is false if maxit iterations did not reach tol. Closed water regions (the
    !! module's notes): b's null-space part is removed first (defect), the preconditioned
    !! residuals are kept free of it, and each region's constant is fixed at the end.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: tol
    integer(ik), intent(in) :: maxit
    logical, intent(out) :: converged
    real(wp) :: bnorm, rz, rzn, alpha, rnorm
    integer(ik) :: it, j, c0, c1
    mc%iters = 0
    mc%resid = 0.0_wp
    mc%defect = 0.0_wp
    mc%nfloat = 0
    mc%p = 0.0_wp
    converged = .true.
    if (mc%nfluid == 0) return
    ! the CG's vectors live on the rows' spans of water cells; r and q vanish outside them
    ! (z and s: the preconditioners write 0 at every cell that is not water)
    call fluid_spans(mc)
    mc%r = 0.0_wp
    mc%q = 0.0_wp
    call find_closed(mc)
    if (mc%nfloat > 0) then
      bnorm = sqrt(fdot(mc, mc%b, mc%b))
      call remove_means(mc, mc%b, rnorm)
      if (bnorm > 0.0_wp) mc%defect = rnorm/bnorm
    end if
    bnorm = sqrt(fdot(mc, mc%b, mc%b))
    if (bnorm == 0.0_wp) then
      mc%p = 0.0_wp
      return
    end if
    call mac_apply(mc, mc%p, mc%q, spans=.true.)
    do j = mc%lo(2), mc%hi(2)
      c0 = mc%slo(j) + (j - 1)*mc%nn(1)
      c1 = mc%shi(j) + (j - 1)*mc%nn(1)
      mc%r(c0:c1) = mc%b(c0:c1) - mc%q(c0:c1)
    end do
    rnorm = sqrt(fdot(mc, mc%r, mc%r))
    mc%resid = rnorm/bnorm
    if (mc%resid <= tol) return
    call mac_precondition(mc, .true.)
    mc%s = mc%z
    rz = fdot(mc, mc%r, mc%z)
    converged = .false.
    do it = 1, maxit
      call mac_apply(mc, mc%s, mc%q, spans=.true.)
      alpha = rz/fdot(mc, mc%s, mc%q)
      !$omp parallel do if (cg_parallel(mc)) default(shared) private(c0, c1) schedule(static)
      do j = mc%lo(2), mc%hi(2)
        c0 = mc%slo(j) + (j - 1)*mc%nn(1)
        c1 = mc%shi(j) + (j - 1)*mc%nn(1)
        mc%p(c0:c1) = mc%p(c0:c1) + alpha*mc%s(c0:c1)
        mc%r(c0:c1) = mc%r(c0:c1) - alpha*mc%q(c0:c1)
      end do
      !$omp end parallel do
      if (mc%nfloat > 0) call remove_means(mc, mc%r)
      mc%iters = it
      rnorm = sqrt(fdot(mc, mc%r, mc%r))
      mc%resid = rnorm/bnorm
      if (mc%resid <= tol) then
        converged = .true.
        exit
      end if
      if (.not. (mc%resid < huge(1.0_wp))) exit
      call mac_precondition(mc, .false.)
      rzn = fdot(mc, mc%r, mc%z)
      !$omp parallel do if (cg_parallel(mc)) default(shared) private(c0, c1) schedule(static)
      do j = mc%lo(2), mc%hi(2)
        c0 = mc%slo(j) + (j - 1)*mc%nn(1)
        c1 = mc%shi(j) + (j - 1)*mc%nn(1)
        mc%s(c0:c1) = mc%z(c0:c1) + (rzn/rz)*mc%s(c0:c1)
      end do
      !$omp end parallel do
      rz = rzn
    end do
    if (converged .and. mc%nfloat > 0) call fix_reference(mc)
  end subroutine mac_solve

  subroutine fluid_spans(mc)
    !! slo(j), shi(j): the first and last water cell of each physical row j (slo > shi: none).
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c
    !$omp parallel do if (cg_parallel(mc)) default(shared) private(i, c) schedule(static)
    do j = mc%lo(2), mc%hi(2)
      mc%slo(j) = mc%hi(1) + 1
      mc%shi(j) = mc%lo(1) - 1
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*mc%nn(1)
        if (mc%cell(c) == CELL_FLUID) then
          mc%slo(j) = min(mc%slo(j), i)
          mc%shi(j) = i
        end if
      end do
    end do
    !$omp end parallel do
  end subroutine fluid_spans

  subroutine mac_precondition(mc, setup)
    !! z = M^-1 r on the water cells (0 elsewhere), M the preconditioner mc%precond, set up
    !! from the assembled matrix first when setup is true; without its null-space part in
    !! closed regions (as found by the last find_closed).
    type(mac_t), intent(inout) :: mc
    logical, intent(in) :: setup
    integer(ik) :: base
    if (mc%precond == PRECOND_MULTIGRID) then
      base = mc%lo(1) - 1 + (mc%lo(2) - 2)*mc%nn(1)
      if (setup) call mg_build(mc%mg, base, mc%nn(1), mc%cell, CELL_FLUID, CELL_AIR, mc%adiag, mc%ai, mc%aj)
      call mg_apply(mc%mg, base, mc%nn(1), mc%r, mc%z)
    else
      if (setup) call mic0(mc)
      call mic0_apply(mc)
    end if
    if (mc%nfloat > 0) call remove_means(mc, mc%z)
  end subroutine mac_precondition

  subroutine find_closed(mc)
    !! Label the closed water regions (rgn, nfloat, rcnt): 4-connected through non-zero
    !! couplings of A, with no row whose sum exceeds ANCHOR of its diagonal (no air or other
    !! Dirichlet term) and no cell in a free rigid body's low-rank term (a uniform pressure on a
    !! free body's boundary moves it, unless the region lies wholly inside the body: that case is
    !! not found, and its solve fails with a message). Flood fill in cell order: the labels do
    !! not depend on anything else. q holds the low-rank cells' mark (scratch before the solve).
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1, nreg, top, k, nb(4), a
    real(wp) :: cpl(4), rs
    logical :: anchored
    n1 = mc%nn(1)
    nreg = 0
    mc%nfloat = 0
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        mc%rgn(i + (j - 1)*n1) = 0
        mc%q(i + (j - 1)*n1) = 0.0_wp
      end do
    end do
    do k = 1, mc%nlr
      mc%q(mc%lrc(k)) = 1.0_wp
    end do
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID .or. mc%rgn(c) /= 0) cycle
        nreg = nreg + 1
        anchored = .false.
        top = 1
        mc%stk(1) = c
        mc%rgn(c) = nreg
        do while (top > 0)
          k = mc%stk(top)
          top = top - 1
          nb = [k + 1, k - 1, k + n1, k - n1]
          cpl = [mc%ai(k), mc%ai(k - 1), mc%aj(k), mc%aj(k - n1)]
          rs = mc%adiag(k) + sum(cpl)
          if (abs(rs) > ANCHOR*abs(mc%adiag(k)) .or. mc%q(k) /= 0.0_wp) anchored = .true.
          do a = 1, 4
            if (cpl(a) == 0.0_wp) cycle
            if (mc%cell(nb(a)) /= CELL_FLUID .or. mc%rgn(nb(a)) /= 0) cycle
            top = top + 1
            mc%stk(top) = nb(a)
            mc%rgn(nb(a)) = nreg
          end do
        end do
        if (anchored) then
          mc%rlab(nreg) = 0
        else
          mc%nfloat = mc%nfloat + 1
          mc%rlab(nreg) = mc%nfloat
        end if
      end do
    end do
    if (mc%nfloat == 0) then
      do j = mc%lo(2), mc%hi(2)
        do i = mc%lo(1), mc%hi(1)
          mc%rgn(i + (j - 1)*n1) = 0
        end do
      end do
      return
    end if
    mc%rcnt(1:mc%nfloat) = 0
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%rgn(c) == 0) cycle
        mc%rgn(c) = mc%rlab(mc%rgn(c))
        if (mc%rgn(c) > 0) mc%rcnt(mc%rgn(c)) = mc%rcnt(mc%rgn(c)) + 1
      end do
    end do
  end subroutine find_closed

  subroutine remove_means(mc, x, removed)
    !! x <- x minus its mean over each closed region (in cell order); removed: the 2-norm of
    !! what was taken away.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(inout) :: x(:)
    real(wp), intent(out), optional :: removed
    integer(ik) :: i, j, c, n1, f
    n1 = mc%nn(1)
    mc%rsum(1:mc%nfloat) = 0.0_wp
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%rgn(c) > 0) mc%rsum(mc%rgn(c)) = mc%rsum(mc%rgn(c)) + x(c)
      end do
    end do
    do f = 1, mc%nfloat
      mc%rsum(f) = mc%rsum(f)/real(mc%rcnt(f), wp)
    end do
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%rgn(c) > 0) x(c) = x(c) - mc%rsum(mc%rgn(c))
      end do
    end do
    if (present(removed)) then
      removed = 0.0_wp
      do f = 1, mc%nfloat
        removed = removed + real(mc%rcnt(f), wp)*mc%rsum(f)**2
      end do
      removed = sqrt(removed)
    end if
  end subroutine remove_means

  subroutine fix_reference(mc)
    !! Each closed region's constant: the pressure extrapolated linearly to the top faces of the
    !! region's highest row (from the cell below where it is in the region) averages zero.
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1, f
    real(wp) :: pt
    n1 = mc%nn(1)
    mc%rlab(1:mc%nfloat) = 0
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%rgn(c) > 0) mc%rlab(mc%rgn(c)) = j
      end do
    end do
    mc%rsum(1:mc%nfloat) = 0.0_wp
    mc%rcnt(1:mc%nfloat) = 0
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        f = mc%rgn(c)
        if (f == 0) cycle
        if (j /= mc%rlab(f)) cycle
        pt = mc%p(c)
        if (mc%rgn(c - n1) == f) pt = mc%p(c) + 0.5_wp*(mc%p(c) - mc%p(c - n1))
        mc%rsum(f) = mc%rsum(f) + pt
        mc%rcnt(f) = mc%rcnt(f) + 1
      end do
    end do
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        f = mc%rgn(c)
        if (f > 0) mc%p(c) = mc%p(c) - mc%rsum(f)/real(mc%rcnt(f), wp)
      end do
    end do
  end subroutine fix_reference

  subroutine mac_project(mc, dt, rho, still)
    !! u <- u - dt/rho grad p on every face next to water (ghost pressure across the
    !! surface); faces next to a wall cell get the wall's normal velocity (a rigid body's
    !! cells their body's), or zero with still = .true. (a correction field: its solve held
    !! every wall still, so a moving body's velocity is no part of it). Marks the faces it set
    !! (uval, vval: FACE_WATER or FACE_WALL); the others are left for mac_extrapolate.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: dt, rho
    logical, intent(in), optional :: still
    integer(ik) :: i, j, k, n1
    real(wp) :: scale, wall
    n1 = mc%nn(1)
    wall = 1.0_wp
    if (present(still)) then
      if (still) wall = 0.0_wp
    end if
    scale = dt/(rho*mc%h)
    mc%uval = 0
    mc%vval = 0
    do j = mc%lo(2) - 1, mc%hi(2) + 1
      do i = mc%lo(1), mc%hi(1) + 1
        k = i + (j - 1)*n1
        call face(k - 1, k, mc%u(k), mc%uval(k), mc%ua(k), mc%rvx)
      end do
    end do
    do j = mc%lo(2), mc%hi(2) + 1
      do i = mc%lo(1) - 1, mc%hi(1) + 1
        k = i + (j - 1)*n1
        call face(k - n1, k, mc%v(k), mc%vval(k), mc%va(k), mc%rvy)
      end do
    end do
  contains
    subroutine face(cl, cr, w, val, a, rv)
      !! Face between cells cl (lower or left) and cr, coefficient a; rv: the solid cells' velocity.
      integer(ik), intent(in) :: cl, cr
      real(wp), intent(inout) :: w
      integer(ik), intent(inout) :: val
      real(wp), intent(in) :: a, rv(:)
      integer(ik) :: tl, tr
      real(wp) :: sa
      tl = mc%cell(cl)
      tr = mc%cell(cr)
      sa = scale*a
      if (tl == CELL_SOLID .or. tr == CELL_SOLID) then
        if (tl /= tr) then   ! a wall face: the wall's (or rigid body's) normal velocity
          w = wall*merge(rv(cl), rv(cr), tl == CELL_SOLID)
          val = FACE_WALL
        end if
      else if (tl == CELL_FLUID .and. tr == CELL_FLUID) then
        w = w - sa*(mc%p(cr) - mc%p(cl))
        val = FACE_WATER
      else if (tl == CELL_FLUID) then
        w = w + sa*mc%p(cl)/mac_theta(mc, cl, cr)
        val = FACE_WATER
      else if (tr == CELL_FLUID) then
        w = w - sa*mc%p(cr)/mac_theta(mc, cr, cl)
        val = FACE_WATER
      end if
    end subroutine face
  end subroutine mac_project

  subroutine mac_extrapolate(mc, w, val, layers)
    !! Faces the projection did not set (val = 0: not next to water) take the mean of their
    !! neighbours on the same lattice that water set (FACE_WATER), layer by layer, so particles at
    !! the surface gather projected values; faces still unset after `layers` layers are zero.
    !! Walls' faces (FACE_WALL) keep their normal velocity and are no source: an air face between
    !! the water and a wall carries the water's velocity, not a mean with the wall's (Bridson 2015,
    !! ch. 4); mac_constrain then imposes the solids' normal velocity inside them. val is left as
    !! it was (one marking serves several fields). A face of layer l lies within l faces of a
    !! water face, so each lattice row is swept only between its rows' first and last water face
    !! (the `layers` rows either side), widened by `layers`: the same result as the whole lattice.
    !! mc's work arrays lev, elo, ehi are used (w is never one of them).
    type(mac_t), intent(inout) :: mc
    real(wp), intent(inout) :: w(:)
    integer(ik), intent(in) :: val(:)
    integer(ik), intent(in) :: layers
    integer(ik) :: i, j, k, n1, n2, l, nb(4), a, cnt, i0, i1, jj
    real(wp) :: sw
    n1 = mc%nn(1)
    n2 = mc%nn(2)
    associate (lev => mc%lev, elo => mc%elo, ehi => mc%ehi)
      do k = 1, size(val)
        lev(k) = val(k)
      end do
      do j = 1, n2
        elo(j) = n1 + 1
        ehi(j) = 0
        do i = 1, n1
          if (val(i + (j - 1)*n1) == FACE_WATER) then
            elo(j) = i
            exit
          end if
        end do
        do i = n1, elo(j), -1
          if (val(i + (j - 1)*n1) == FACE_WATER) then
            ehi(j) = i
            exit
          end if
        end do
      end do
      do l = 1, layers
        do j = 2, n2 - 1
          i0 = n1 + 1
          i1 = 0
          do jj = max(1, j - layers), min(n2, j + layers)
            i0 = min(i0, elo(jj))
            i1 = max(i1, ehi(jj))
          end do
          do i = max(2, i0 - layers), min(n1 - 1, i1 + layers)
            k = i + (j - 1)*n1
            if (lev(k) /= 0) cycle
            nb = [k - 1, k + 1, k - n1, k + n1]
            cnt = 0
            sw = 0.0_wp
            do a = 1, 4
              if (lev(nb(a)) >= 1 .and. lev(nb(a)) <= l) then
                cnt = cnt + 1
                sw = sw + w(nb(a))
              end if
            end do
            if (cnt > 0) then
              w(k) = sw/real(cnt, wp)
              lev(k) = l + 1
            end if
          end do
        end do
      end do
      do k = 1, size(val)
        if (lev(k) == 0) w(k) = 0.0_wp
      end do
    end associate
  end subroutine mac_extrapolate

  subroutine mac_constrain(mc, u, v, still)
    !! After the extrapolation, the faces inside solid cells (Bridson 2015, ch. 4: the solid's
    !! normal velocity is imposed where the extrapolation reached into it): between two cells of a
    !! rigid body, both components are the body's velocity (0 with still); beyond a closed domain
    !! wall, the wall-normal component is the wall's, 0, and the tangential one stays extrapolated
    !! (slip). Particles whose domains reach past a wall then gather no velocity into it.
    type(mac_t), intent(in) :: mc
    real(wp), intent(inout) :: u(:), v(:)
    logical, intent(in) :: still
    integer(ik) :: i, j, k, n1
    real(wp) :: wall
    n1 = mc%nn(1)
    wall = merge(0.0_wp, 1.0_wp, still)
    do j = 1, mc%nn(2)
      do i = 2, n1
        k = i + (j - 1)*n1
        if (mc%cell(k - 1) /= CELL_SOLID .or. mc%cell(k) /= CELL_SOLID) cycle
        if (i - 1 >= mc%lo(1) .and. i <= mc%hi(1) .and. j >= mc%lo(2) .and. j <= mc%hi(2)) then
          u(k) = wall*mc%rvx(k)   ! inside a rigid body
        else if (i < mc%lo(1) .or. i > mc%hi(1) + 1) then
          u(k) = 0.0_wp   ! beyond the left or right wall: its normal
        end if
      end do
    end do
    do j = 2, mc%nn(2)
      do i = 1, n1
        k = i + (j - 1)*n1
        if (mc%cell(k - n1) /= CELL_SOLID .or. mc%cell(k) /= CELL_SOLID) cycle
        if (j - 1 >= mc%lo(2) .and. j <= mc%hi(2) .and. i >= mc%lo(1) .and. i <= mc%hi(1)) then
          v(k) = wall*mc%rvy(k)   ! inside a rigid body
        else if (j < mc%lo(2) .or. j > mc%hi(2) + 1) then
          v(k) = 0.0_wp   ! beyond the bottom or top wall
        end if
      end do
    end do
  end subroutine mac_constrain

  subroutine mac_ghost_pressure(mc)
    !! pe: the pressure in water cells, the mean ghost value p_w (1 - 1/theta) of the water
    !! neighbours in air cells next to water, 0 in other air cells. Beyond the domain's edges
    !! the particle interpolation extrapolates linearly (cpdi_incompressible edge_weights).
    type(mac_t), intent(inout) :: mc
    integer(ik) :: i, j, c, n1, nb(4), a, cnt
    real(wp) :: sg
    n1 = mc%nn(1)
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) == CELL_FLUID) then
          mc%pe(c) = mc%p(c)
          cycle
        end if
        nb = [c - 1, c + 1, c - n1, c + n1]
        cnt = 0
        sg = 0.0_wp
        do a = 1, 4
          if (mc%cell(nb(a)) == CELL_FLUID) then
            cnt = cnt + 1
            sg = sg + mc%p(nb(a))*(1.0_wp - 1.0_wp/mac_theta(mc, nb(a), c))
          end if
        end do
        mc%pe(c) = 0.0_wp
        if (cnt > 0) mc%pe(c) = sg/real(cnt, wp)
      end do
    end do
  end subroutine mac_ghost_pressure
end module cpdi_pressure
