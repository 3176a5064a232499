!> Uniform background grid with bilinear nodal functions and wall conditions.
module cpdi_grid
  !! The physical domain is `[origin, origin + ncell*h]`. Its four edges are walls of
  !! kind open, slip or noslip. The node arrays extend `GRID_PAD` cells beyond every
  !! edge so that GIMP supports and CPDI corners of particles near a wall have nodes to
  !! map to; nodes on or beyond a closed wall have their wall-normal (slip) or full
  !! (noslip) velocity set to zero.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT, CPDI_ERR_ALLOC
  implicit none
  private

  integer(ik), parameter, public :: WALL_OPEN = 0     !! no condition
  integer(ik), parameter, public :: WALL_SLIP = 1     !! zero normal velocity
  integer(ik), parameter, public :: WALL_NOSLIP = 2   !! zero velocity
  integer(ik), parameter, public :: GRID_PAD = 2      !! ghost cells beyond each edge
  integer(ik), parameter, public :: MAX_NODES = 200000000 !! guard against absurd grids

  type, public :: grid_t
    !! Geometry and nodal fields (structure of arrays, one entry per node).
    real(wp) :: origin(2) = 0.0_wp        !! lower-left corner of the physical domain [m]
    real(wp) :: h = 0.0_wp                !! cell size [m]
    real(wp) :: gorig(2) = 0.0_wp         !! position of node (1,1) [m]
    integer(ik) :: ncell(2) = 0           !! physical cells per direction
    integer(ik) :: nn(2) = 0              !! nodes per direction, padding included
    integer(ik) :: nnodes = 0             !! total nodes
    integer(ik) :: walls(4) = WALL_OPEN   !! left, right, bottom, top
    integer(ik) :: wall_node(4) = 0       !! node index (per axis) of each wall plane
    integer(ik) :: nf = 0                 !! velocity fields (1, or one per body with contact)
    real(wp), allocatable :: m(:, :)      !! nodal mass (node, field)
    real(wp), allocatable :: px(:, :), py(:, :) !! nodal momentum, then velocity at t^n
    real(wp), allocatable :: fx(:, :), fy(:, :) !! nodal force
    real(wp), allocatable :: vx(:, :), vy(:, :) !! nodal velocity at t^{n+1}
    real(wp), allocatable :: mr(:, :)     !! mass of rigid particles at the node
    real(wp), allocatable :: prx(:, :), pry(:, :) !! momentum of rigid particles at the node
    real(wp), allocatable :: gmx(:, :), gmy(:, :) !! mass gradient sum m_p grad S_ip (contact normals)
    real(wp), allocatable :: gv(:, :)     !! nodal volume sum S_ip V_p (contact fullness)
    real(wp), allocatable :: infrac(:)    !! inside_fraction of every node (set with the fields)
  contains
    procedure :: node_id => grid_node_id
    procedure :: node_x => grid_node_x
  end type grid_t

  public :: grid_init, grid_fields, grid_apply_walls, inside_fraction, hold_on_walls, grid_clear_p2g, grid_box

contains

  subroutine grid_init(g, origin, ncell, h, walls, st)
    !! Validate and allocate a grid.
    type(grid_t), intent(inout) :: g
    real(wp), intent(in) :: origin(2)   !! lower-left corner [m]
    integer(ik), intent(in) :: ncell(2) !! physical cells per direction
    real(wp), intent(in) :: h           !! cell size [m]
    integer(ik), intent(in) :: walls(4) !! wall kinds: left, right, bottom, top
    type(status_t), intent(inout) :: st
    character(len=160) :: buf

    if (.not. (h > 0.0_wp) .or. h > huge(1.0_wp)) then
      write (buf, '(a,es12.4,a)') 'grid cell size is ', h, '; it must be a positive finite length in m'
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    if (any(origin /= origin) .or. any(abs(origin) > huge(1.0_wp))) then
      call st%set(CPDI_ERR_INPUT, 'grid origin is not finite; give two finite coordinates in m')
      return
    end if
    if (any(ncell < 1)) then
      write (buf, '(a,2i8,a)') 'grid has ', ncell, ' cells; each direction needs at least one cell'
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    if (any(walls < WALL_OPEN) .or. any(walls > WALL_NOSLIP)) then
      call st%set(CPDI_ERR_INPUT, 'wall kind must be 0 (open), 1 (slip) or 2 (noslip)')
      return
    end if
    if (real(ncell(1) + 1 + 2*GRID_PAD, wp)*real(ncell(2) + 1 + 2*GRID_PAD, wp) > MAX_NODES) then
      call st%set(CPDI_ERR_INPUT, 'grid has more than 2e8 nodes; use a larger cell size')
      return
    end if
    g%origin = origin
    g%h = h
    g%ncell = ncell
    g%nn = ncell + 1 + 2*GRID_PAD
    g%nnodes = g%nn(1)*g%nn(2)
    g%gorig = origin - GRID_PAD*h
    g%walls = walls
    g%wall_node = [GRID_PAD + 1, GRID_PAD + 1 + ncell(1), GRID_PAD + 1, GRID_PAD + 1 + ncell(2)]
    g%nf = 0
    call grid_fields(g, 1_ik, .false., .false., st)
  end subroutine grid_init

  subroutine grid_fields(g, nf, rigid, volumes, st)
    !! (Re)allocate the nodal arrays for nf velocity fields (no-op if already so). The
    !! rigid-particle arrays (mr, prx, pry) are sized only when rigid particles exist, the
    !! normals (gmx, gmy) only for several fields, and the fields' volumes (gv) only with
    !! `volumes` (contact: the walls' volume constraint needs them for one body too): memory
    !! is spent on what the run uses.
    type(grid_t), intent(inout) :: g
    integer(ik), intent(in) :: nf
    logical, intent(in) :: rigid, volumes
    type(status_t), intent(inout) :: st
    integer :: ierr, n, nr
    integer(ik) :: k
    if (allocated(g%m)) then
      if (g%nf == nf .and. ((size(g%mr, 2) > 0) .eqv. rigid) .and. ((size(g%gv, 2) > 0) .eqv. volumes)) return
    end if
    if (allocated(g%m)) deallocate (g%m, g%px, g%py, g%fx, g%fy, g%vx, g%vy, g%mr, g%prx, g%pry, g%gmx, g%gmy, g%gv)
    if (allocated(g%infrac)) deallocate (g%infrac)
    n = g%nnodes
    nr = merge(nf, 0_ik, rigid)
    allocate (g%m(n, nf), g%px(n, nf), g%py(n, nf), g%fx(n, nf), g%fy(n, nf), g%vx(n, nf), g%vy(n, nf), &
              g%mr(n, nr), g%prx(n, nr), g%pry(n, nr), g%gmx(n, merge(nf, 0_ik, nf > 1)), &
              g%gmy(n, merge(nf, 0_ik, nf > 1)), g%gv(n, merge(nf, 0_ik, volumes)), g%infrac(n), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the grid; use a larger cell size')
      g%nf = 0
      return
    end if
    g%nf = nf
    g%m = 0.0_wp
    g%px = 0.0_wp
    g%py = 0.0_wp
    g%fx = 0.0_wp
    g%fy = 0.0_wp
    g%vx = 0.0_wp
    g%vy = 0.0_wp
    g%mr = 0.0_wp
    g%prx = 0.0_wp
    g%pry = 0.0_wp
    do k = 1, n   ! a table: contact and the walls' volume constraint ask for it every step
      g%infrac(k) = node_inside_fraction(g, k)
    end do
  end subroutine grid_fields

  pure integer(ik) function grid_node_id(self, i, j)
    !! Linear index of node (i, j), both 1-based and padding included.
    class(grid_t), intent(in) :: self
    integer(ik), intent(in) :: i, j
    grid_node_id = i + (j - 1)*self%nn(1)
  end function grid_node_id

  pure function grid_node_x(self, k) result(x)
    !! Position of node with linear index k.
    class(grid_t), intent(in) :: self
    integer(ik), intent(in) :: k
    real(wp) :: x(2)
    x(1) = self%gorig(1) + real(mod(k - 1, self%nn(1)), wp)*self%h
    x(2) = self%gorig(2) + real((k - 1)/self%nn(1), wp)*self%h
  end function grid_node_x

  subroutine grid_clear_p2g(g, k0, k1)
    !! Zero what P2G sums (mass, momentum, force of every field) on nodes k0..k1.
    !! Orphaned worksharing (a static split of the nodes; no barrier at its end: the
    !! caller's next worksharing loop or barrier orders it). A routine of its own because
    !! inlined into p2g, beside the strip hand-out, this loop spilled its pointers and
    !! strides to vector registers, and P2G on one thread slowed (measured:
    !! docs/notes/threads.md, "One thread after the change").
    type(grid_t), intent(inout) :: g
    integer(ik), intent(in) :: k0, k1
    call clear_fields(k0, k1, g%nnodes, g%nf, g%m, g%px, g%py, g%fx, g%fy)
  end subroutine grid_clear_p2g

  subroutine clear_fields(k0, k1, nn, nf, m, px, py, fx, fy)
    !! grid_clear_p2g on plain arrays.
    integer(ik), intent(in) :: k0, k1, nn, nf
    real(wp), intent(inout) :: m(nn, nf), px(nn, nf), py(nn, nf), fx(nn, nf), fy(nn, nf)
    integer(ik) :: k, f
    do f = 1, nf
      !$omp do schedule(static) private(k)
      do k = k0, k1
        m(k, f) = 0.0_wp
        px(k, f) = 0.0_wp
        py(k, f) = 0.0_wp
        fx(k, f) = 0.0_wp
        fy(k, f) = 0.0_wp
      end do
      !$omp end do nowait
    end do
  end subroutine clear_fields

  subroutine grid_apply_walls(g, vx, vy, gv, vfull)
    !! Impose the wall conditions on a nodal velocity (or momentum) field: every node on
    !! or beyond a closed wall loses its normal component (slip) or all of it (noslip).
    !! With `gv` (the field's nodal volume) and `vfull` (fullness h^2) the wall obeys the
    !! volume constraint of body contact: a field passes a wall node when it fills the inside
    !! part of that node's support less than `fullness` times as well as it fills the next
    !! node inward (fill = volume / inside fraction of the support), i.e. when there is a gap
    !! between the body and the wall. Without this a falling body stops about a cell above
    !! the floor, as soon as its domains reach the floor node's support. A body touching the
    !! wall fills both nodes alike, and a layer thinner than a cell lying on the wall (a flow
    !! front) fills the wall node better than the next: both stay held. The ratio makes the
    !! test independent of how much of the nodes' width the body covers (its edges).
    type(grid_t), intent(in) :: g
    real(wp), intent(inout) :: vx(:), vy(:)
    real(wp), intent(in), optional :: gv(:)
    real(wp), intent(in), optional :: vfull
    integer(ik) :: i, j, k
    logical :: vol

    vol = present(gv)   ! without volumes no node is released: released is not called
    if (g%walls(1) /= WALL_OPEN) then
      do j = 1, g%nn(2)
        do i = 1, g%wall_node(1)
          k = i + (j - 1)*g%nn(1)
          if (vol) then
            if (released(k, k + 1)) cycle
          end if
          vx(k) = 0.0_wp
          if (g%walls(1) == WALL_NOSLIP) vy(k) = 0.0_wp
        end do
      end do
    end if
    if (g%walls(2) /= WALL_OPEN) then
      do j = 1, g%nn(2)
        do i = g%wall_node(2), g%nn(1)
          k = i + (j - 1)*g%nn(1)
          if (vol) then
            if (released(k, k - 1)) cycle
          end if
          vx(k) = 0.0_wp
          if (g%walls(2) == WALL_NOSLIP) vy(k) = 0.0_wp
        end do
      end do
    end if
    if (g%walls(3) /= WALL_OPEN) then
      do j = 1, g%wall_node(3)
        do i = 1, g%nn(1)
          k = i + (j - 1)*g%nn(1)
          if (vol) then
            if (released(k, k + g%nn(1))) cycle
          end if
          vy(k) = 0.0_wp
          if (g%walls(3) == WALL_NOSLIP) vx(k) = 0.0_wp
        end do
      end do
    end if
    if (g%walls(4) /= WALL_OPEN) then
      do j = g%wall_node(4), g%nn(2)
        do i = 1, g%nn(1)
          k = i + (j - 1)*g%nn(1)
          if (vol) then
            if (released(k, k - g%nn(1))) cycle
          end if
          vy(k) = 0.0_wp
          if (g%walls(4) == WALL_NOSLIP) vx(k) = 0.0_wp
        end do
      end do
    end if
  contains
    logical function released(k, kin)
      !! Field passes wall node k (kin: the next node inward).
      integer(ik), intent(in) :: k, kin
      released = .false.
      if (.not. vol) return
      if (kin < 1 .or. kin > g%nnodes) return
      released = gv(k)*inside_fraction(g, kin) < (vfull/g%h**2)*gv(kin)*inside_fraction(g, k)
    end function released
  end subroutine grid_apply_walls
  pure real(wp) function inside_fraction(g, k)
    !! Fraction of node k's bilinear hat integral that lies inside the physical domain
    !! (1 inside, 1/2 on a wall, 1/4 in a corner, 0 beyond): the table g%infrac once the
    !! fields are allocated (grid_fields), else node_inside_fraction.
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: k
    if (allocated(g%infrac)) then
      inside_fraction = g%infrac(k)
    else
      inside_fraction = node_inside_fraction(g, k)
    end if
  end function inside_fraction

  pure real(wp) function node_inside_fraction(g, k)
    !! inside_fraction of node k, computed from its position.
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: k
    real(wp) :: x(2), lo(2), hi(2)
    integer :: a
    x = g%node_x(k)
    lo = g%origin
    hi = g%origin + real(g%ncell, wp)*g%h
    node_inside_fraction = 1.0_wp
    do a = 1, 2
      node_inside_fraction = node_inside_fraction*hat_part(x(a) - lo(a), g%h)*hat_part(hi(a) - x(a), g%h)
    end do
  end function node_inside_fraction

  pure real(wp) function hat_part(d, h)
    !! Share of a 1D hat of half-width h centred at distance d inside a boundary.
    real(wp), intent(in) :: d, h
    if (d >= h) then
      hat_part = 1.0_wp
    else if (d >= 0.0_wp) then
      hat_part = 1.0_wp - 0.5_wp*(1.0_wp - d/h)**2
    else if (d > -h) then
      hat_part = 0.5_wp*(1.0_wp + d/h)**2
    else
      hat_part = 0.0_wp
    end if
  end function hat_part

  pure subroutine grid_box(g, xmin, xmax, closed)
    !! The grid's extent (its lower-left and upper-right corners) and which of its edges are
    !! walls (left, right, bottom, top): what every G2P needs to hold particles on the walls.
    type(grid_t), intent(in) :: g
    real(wp), intent(out) :: xmin(2), xmax(2)
    logical, intent(out), optional :: closed(4)
    xmin = g%origin
    xmax = g%origin + real(g%ncell, wp)*g%h
    if (present(closed)) closed = g%walls /= WALL_OPEN
  end subroutine grid_box

  pure subroutine hold_on_walls(x, xmin, xmax, closed, nclamp)
    !! Particles are held on closed walls (the grid already stops their normal motion at the
    !! wall nodes; this removes the residual drift of wide supports); nclamp counts them.
    real(wp), intent(inout) :: x(2)
    real(wp), intent(in) :: xmin(2), xmax(2)
    logical, intent(in) :: closed(4)
    integer(ik), intent(inout) :: nclamp
    integer :: a
    do a = 1, 2   ! closed = (left, right, bottom, top)
      if (closed(2*a - 1) .and. x(a) < xmin(a)) then
        x(a) = xmin(a)
        nclamp = nclamp + 1
      end if
      if (closed(2*a) .and. x(a) > xmax(a)) then
        x(a) = xmax(a)
        nclamp = nclamp + 1
      end if
    end do
  end subroutine hold_on_walls
end module cpdi_grid
