!> Free rigid bodies in the incompressible water: three degrees of freedom per body, coupled to the
!> pressure through the boundary-flux operator of Batty, Bertails & Bridson (2007).
module cpdi_rigid_body
  !! A body is the set of particles of one `rigid_body` material that share a body index. Its state
  !! is read from its particles at the start of every step (mass M, centre X, moment of inertia I
  !! about X, velocity V and angular velocity omega, least squares over the particles), so a
  !! checkpoint of the particles restarts it exactly. One step of length dt (docs/fsi_incompressible.md):
  !!
  !! 1. rb_begin: the state from the particles (omega from their point masses, whose velocities are
  !!    the rigid field; I includes their domains' own inertia); V* = V + dt (g + the mean body force).
  !! 2. The body's particles spread their volume over the face lattices (cpdi_incompressible), into
  !!    the solid fractions w_f of the faces; the body's share of face f is w_f^b = w_f V_b,f / V_s,f.
  !! 3. rb_assemble: in every water cell c the body's boundary flux J_c . U (U = [V, omega]) joins the
  !!    cell's constraint, J_c = h [g^x_c, g^y_c, g^y_c (x_c - X) - g^x_c (y_c - Y)] with
  !!    g^x_c = w^b(right) - w^b(left), g^y_c = w^b(top) - w^b(bottom): the rigid field's flux through
  !!    the cell's faces, exact for a rigid motion. The kinetic-energy minimisation under the
  !!    constraint adds rho J M^-1 J^T (rank 3 per body) to the pressure matrix (cpdi_pressure's
  !!    low-rank term) and -(rho / dt) J . U* to the right-hand side.
  !!    After the solve the water leaves the body where it would pull on it next to the void
  !!    (cpdi_incompressible separate_from_bodies: such cells become air, and the system is solved again).
  !! 4. rb_impulse: U = U* + dt M^-1 J^T p, the pressure's impulse on the body (its transpose):
  !!    a uniform pressure gives none (the sums of g telescope), a hydrostatic one rho g sum_f w_f^b h^2.
  !! 5. rb_walls: the closed walls hold the body: the corners of its particles' domains may not cross
  !!    a wall (speculative contacts, projected Gauss-Seidel on the normal impulses, Coulomb friction
  !!    with the material's coefficient). The impulses are non-negative and restitution is zero, so
  !!    contact removes energy only.
  !! 6. rb_move: particles move rigidly (exact rotation of their offsets, domains and F); velocity
  !!    V + omega x r; L the rotation's velocity gradient.
  !!
  !! The body sets no acoustic step: the step's limit is its fastest particle's speed, as the water's.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  use cpdi_particles, only: particles_t
  use cpdi_grid, only: grid_t, grid_box, WALL_OPEN
  use cpdi_pressure, only: mac_t, CELL_FLUID, CELL_SOLID
  implicit none
  private

  integer(ik), parameter :: CONTACT_SWEEPS = 30   !! Gauss-Seidel sweeps over a body's contacts

  type, public :: rbody_t
    !! The free rigid bodies of a run and their work storage.
    integer(ik) :: n = 0                         !! bodies
    integer(ik), allocatable :: slot(:)          !! per particle: its body (0: not a free rigid body)
    real(wp), allocatable :: m(:), inertia(:)    !! mass [kg/m], moment of inertia about xc [kg m^2/m]
    real(wp), allocatable :: xc(:, :)            !! centre of mass [m]
    real(wp), allocatable :: v(:, :), w(:)       !! velocity [m/s], angular velocity [1/s]
    real(wp), allocatable :: v0(:, :)            !! velocity at the step's start [m/s]
    logical, allocatable :: flight(:)            !! no water and no wall acted on the body this step
    real(wp), allocatable :: friction(:)         !! Coulomb coefficient against the walls
    real(wp), allocatable :: vol(:)              !! volume [m^2/m]
    real(wp), allocatable :: xv(:, :)            !! centroid of the volume [m] (the mass centre's if uniform)
    logical, allocatable :: lock(:, :)           !! (3, n): a wall holds this degree of freedom in the solve
    real(wp), allocatable :: force(:, :)         !! (3, n): the water's force and torque of the last step
    real(wp), allocatable :: uvb(:, :), vvb(:, :) !! per body: its volume on the u and v face lattices
    integer(ik), allocatable :: cp(:)            !! contact candidates (particles; up to 4 walls each)
    real(wp), allocatable :: cn(:, :), cr(:, :)  !! their wall's normal, the touching corner's offset from xc
    real(wp), allocatable :: cl(:), ct(:), cmin(:)   !! impulses (normal, friction), target normal speed
  end type rbody_t

  public :: rb_prepare, rb_begin, rb_assemble, rb_impulse, rb_walls, rb_move

contains

  subroutine rb_prepare(rb, free, body, p, friction, nnodes, st)
    !! Number the bodies (one per body index among the particles of free materials) and size the
    !! storage. free(m): material m is a free rigid body; friction(m) its wall friction coefficient.
    type(rbody_t), intent(inout) :: rb
    logical, intent(in) :: free(:)
    integer(ik), intent(in) :: body(:)
    type(particles_t), intent(in) :: p
    real(wp), intent(in) :: friction(:)
    integer(ik), intent(in) :: nnodes
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, nmax, ierr, npart
    integer(ik), allocatable :: map(:)
    if (allocated(rb%slot)) deallocate (rb%slot, rb%m, rb%inertia, rb%xc, rb%v, rb%w, rb%friction, rb%vol, &
                                         rb%force, rb%v0, rb%flight, rb%uvb, rb%vvb, rb%cp, rb%cn, rb%cl, rb%ct, rb%cmin, &
                                         rb%cr, rb%xv, rb%lock)
    rb%n = 0
    nmax = 0
    if (p%n > 0) nmax = maxval(body)
    allocate (map(max(nmax, 1)), rb%slot(p%n), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the rigid bodies; use fewer particles')
      return
    end if
    map = 0
    rb%slot = 0
    npart = 0
    do ip = 1, p%n
      if (.not. free(p%mat(ip))) cycle
      if (map(body(ip)) == 0) then
        rb%n = rb%n + 1
        map(body(ip)) = rb%n
      end if
      rb%slot(ip) = map(body(ip))
      npart = npart + 1
    end do
    allocate (rb%m(rb%n), rb%inertia(rb%n), rb%xc(2, rb%n), rb%v(2, rb%n), rb%w(rb%n), rb%friction(rb%n), rb%vol(rb%n), &
              rb%v0(2, rb%n), rb%flight(rb%n), &
              rb%force(3, rb%n), rb%uvb(nnodes, rb%n), rb%vvb(nnodes, rb%n), rb%cp(4*npart), rb%cn(2, 4*npart), &
              rb%cl(4*npart), rb%ct(4*npart), rb%cmin(4*npart), rb%cr(2, 4*npart), rb%xv(2, rb%n), rb%lock(3, rb%n), &
              stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the rigid bodies; use a larger cell size')
      return
    end if
    rb%m = 0.0_wp; rb%inertia = 0.0_wp; rb%xc = 0.0_wp; rb%v = 0.0_wp; rb%w = 0.0_wp; rb%force = 0.0_wp
    rb%xv = 0.0_wp; rb%lock = .false.; rb%flight = .true.; rb%v0 = 0.0_wp; rb%vol = 0.0_wp
    rb%uvb = 0.0_wp; rb%vvb = 0.0_wp
    rb%friction = 0.0_wp
    do ip = 1, p%n   ! (material_init has refused a negative coefficient)
      if (rb%slot(ip) /= 0) rb%friction(rb%slot(ip)) = friction(p%mat(ip))
    end do
  end subroutine rb_prepare

  subroutine rb_begin(rb, p, gravity, dt)
    !! Mass, centre, inertia, velocity and angular velocity of every body from its particles, then
    !! the velocity after gravity and body forces: V* = V + dt (g + sum m b / M).
    type(rbody_t), intent(inout) :: rb
    type(particles_t), intent(in) :: p
    real(wp), intent(in) :: gravity(2), dt
    integer(ik) :: ip, b
    real(wp) :: mom(2, rb%n), ang(rb%n), fb(2, rb%n), jp(rb%n), r(2), mp
    if (rb%n == 0) return
    rb%m = 0.0_wp
    rb%vol = 0.0_wp
    rb%xc = 0.0_wp
    rb%xv = 0.0_wp
    rb%lock = .false.
    mom = 0.0_wp
    fb = 0.0_wp
    do ip = 1, p%n
      b = rb%slot(ip)
      if (b == 0) cycle
      mp = p%m(ip)
      rb%m(b) = rb%m(b) + mp
      rb%vol(b) = rb%vol(b) + p%vol(ip)
      rb%xv(:, b) = rb%xv(:, b) + p%vol(ip)*p%x(:, ip)
      rb%xc(:, b) = rb%xc(:, b) + mp*p%x(:, ip)
      mom(:, b) = mom(:, b) + mp*p%v(:, ip)
      fb(:, b) = fb(:, b) + mp*p%bf(:, ip)
    end do
    do b = 1, rb%n
      rb%xc(:, b) = rb%xc(:, b)/rb%m(b)
      rb%xv(:, b) = rb%xv(:, b)/rb%vol(b)
      rb%v(:, b) = mom(:, b)/rb%m(b)
    end do
    rb%inertia = 0.0_wp
    ang = 0.0_wp
    jp = 0.0_wp
    do ip = 1, p%n
      b = rb%slot(ip)
      if (b == 0) cycle
      mp = p%m(ip)
      r = p%x(:, ip) - rb%xc(:, b)
      ! a parallelogram spanned by +-r1 +-r2 about its centre: m (|r1|^2 + |r2|^2) / 3
      rb%inertia(b) = rb%inertia(b) + mp*(r(1)**2 + r(2)**2) + mp*sum(p%r(:, ip)**2)/3.0_wp
      jp(b) = jp(b) + mp*(r(1)**2 + r(2)**2)
      ang(b) = ang(b) + mp*(r(1)*(p%v(2, ip) - rb%v(2, b)) - r(2)*(p%v(1, ip) - rb%v(1, b)))
    end do
    do b = 1, rb%n
      ! the particles' velocities are the rigid field at their centres: omega from their point
      ! masses' inertia (the domains' own spin is no part of their velocities)
      rb%w(b) = 0.0_wp
      if (jp(b) > 0.0_wp) rb%w(b) = ang(b)/jp(b)
      rb%v0(:, b) = rb%v(:, b)
      rb%v(:, b) = rb%v(:, b) + dt*(gravity + fb(:, b)/rb%m(b))
      rb%flight(b) = .true.
    end do
  end subroutine rb_begin

  subroutine rb_assemble(rb, mc, g, wu, wv, uvs, vvs, rho, dt)
    !! (rb%flight: cleared for the bodies that bound a water cell.)
    !! The bodies' rows of the pressure equation: the low-rank term rho J M^-1 J^T in mc (lrc, lrb,
    !! lrj, lrd, nlr) and -(rho / dt) J . U* added to the right-hand side of every water cell they
    !! bound. wu, wv: the solid fractions of the faces (all solids, as cpdi_coupling left them: a face
    !! beyond W_FULL, or closing a water cell against the solid's inside, is full), uvs, vvs: the
    !! solids' face volumes. Faces next to a wall cell carry the wall's velocity: no share of a body.
    !! Per axis, the body's fractions are scaled so that its volume on that face lattice is its
    !! particles' volume V, and its rotation's flux is taken about the centroid of that volume
    !! (xv on the v lattice, yu on the u lattice): a hydrostatic pressure then gives rho g V and
    !! no torque wherever the body lies on the grid (the full faces would otherwise count the
    !! volume of the cells they close: 0.3-0.4 % too much buoyancy, and a torque, off the cell lines).
    type(rbody_t), intent(inout) :: rb
    type(mac_t), intent(inout) :: mc
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: wu(:), wv(:), uvs(:), vvs(:), rho, dt
    integer(ik) :: i, j, c, n1, b
    real(wp) :: gx, gy, xc(2), jc(3), su(rb%n), sv(rb%n), yu(rb%n), xv(rb%n), a
    mc%nlr = 0
    if (rb%n == 0) return
    n1 = mc%nn(1)
    do b = 1, rb%n
      mc%lrd(:, b) = rho*[1.0_wp/rb%m(b), 1.0_wp/rb%m(b), 1.0_wp/rb%inertia(b)]
      where (rb%lock(:, b)) mc%lrd(:, b) = 0.0_wp   ! held by a wall in this solve: no mobility
    end do
    ! the body's volume and its centroid on each face lattice (u faces at cell-centre height, v faces
    ! at cell-centre abscissa), the whole padded lattice: a body partly beyond an open side keeps
    ! its fractions
    su = 0.0_wp
    sv = 0.0_wp
    yu = 0.0_wp
    xv = 0.0_wp
    do j = 1, mc%nn(2)
      do i = 1, n1
        c = i + (j - 1)*n1
        xc = g%gorig + ([real(i, wp), real(j, wp)] - 0.5_wp)*g%h
        do b = 1, rb%n
          a = frac(c, wu, uvs, rb%uvb(:, b))
          su(b) = su(b) + a
          yu(b) = yu(b) + a*xc(2)
          a = frac(c, wv, vvs, rb%vvb(:, b))
          sv(b) = sv(b) + a
          xv(b) = xv(b) + a*xc(1)
        end do
      end do
    end do
    do b = 1, rb%n
      if (su(b) > 0.0_wp) yu(b) = yu(b)/su(b)
      if (sv(b) > 0.0_wp) xv(b) = xv(b)/sv(b)
      su(b) = merge(rb%vol(b)/(su(b)*mc%h**2), 0.0_wp, su(b) > 0.0_wp)
      sv(b) = merge(rb%vol(b)/(sv(b)*mc%h**2), 0.0_wp, sv(b) > 0.0_wp)
    end do
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) cycle
        xc = g%gorig + ([real(i, wp), real(j, wp)] - 0.5_wp)*g%h
        do b = 1, rb%n
          gx = su(b)*(share(c + 1, c, c + 1, wu, uvs, rb%uvb(:, b)) - share(c, c - 1, c, wu, uvs, rb%uvb(:, b)))
          gy = sv(b)*(share(c + n1, c, c + n1, wv, vvs, rb%vvb(:, b)) - share(c, c - n1, c, wv, vvs, rb%vvb(:, b)))
          if (gx == 0.0_wp .and. gy == 0.0_wp) cycle
          ! the rotation's flux about the mass centre X, with the lattice volumes' centroid moved
          ! onto the particles' volume centroid (the shift that makes a hydrostatic torque vanish
          ! about the centre of buoyancy of a uniform body, and keeps a ballasted body's couple)
          jc = mc%h*[gx, gy, gy*(xc(1) - xv(b) + rb%xv(1, b) - rb%xc(1, b)) &
                     - gx*(xc(2) - yu(b) + rb%xv(2, b) - rb%xc(2, b))]
          mc%nlr = mc%nlr + 1
          mc%lrc(mc%nlr) = c
          mc%lrb(mc%nlr) = b
          mc%lrj(:, mc%nlr) = jc
          rb%flight(b) = .false.
          ! (a degree of freedom a wall holds carries no flux in this solve: the wall takes its push)
          mc%b(c) = mc%b(c) - (rho/dt)*(merge(0.0_wp, jc(1)*rb%v(1, b), rb%lock(1, b)) &
                                        + merge(0.0_wp, jc(2)*rb%v(2, b), rb%lock(2, b)) &
                                        + merge(0.0_wp, jc(3)*rb%w(b), rb%lock(3, b)))
        end do
      end do
    end do
  contains
    pure real(wp) function frac(f, w, vs, vb)
      !! Body b's share of the solid fraction of face f.
      integer(ik), intent(in) :: f
      real(wp), intent(in) :: w(:), vs(:), vb(:)
      frac = 0.0_wp
      if (vs(f) > 0.0_wp) frac = w(f)*vb(f)/vs(f)
    end function frac

    pure real(wp) function share(f, cl, cr, w, vs, vb)
      !! Body b's solid fraction of face f between cells cl and cr (none next to a wall cell).
      integer(ik), intent(in) :: f, cl, cr
      real(wp), intent(in) :: w(:), vs(:), vb(:)
      share = 0.0_wp
      if (mc%cell(cl) == CELL_SOLID .or. mc%cell(cr) == CELL_SOLID) return
      share = frac(f, w, vs, vb)
    end function share
  end subroutine rb_assemble

  subroutine rb_impulse(rb, mc, dt)
    !! U <- U* + dt M^-1 J^T p: the pressure's impulse on every body; force: the water's force and
    !! torque over the step (J^T p) [N/m, N m/m].
    type(rbody_t), intent(inout) :: rb
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: dt
    integer(ik) :: e, b
    if (rb%n == 0) return
    rb%force = 0.0_wp
    do e = 1, mc%nlr
      b = mc%lrb(e)
      rb%force(:, b) = rb%force(:, b) + mc%lrj(:, e)*mc%p(mc%lrc(e))
    end do
    do b = 1, rb%n   ! (a degree of freedom held by a wall: its impulse goes to the wall, rb_walls)
      if (.not. rb%lock(1, b)) rb%v(1, b) = rb%v(1, b) + dt*rb%force(1, b)/rb%m(b)
      if (.not. rb%lock(2, b)) rb%v(2, b) = rb%v(2, b) + dt*rb%force(2, b)/rb%m(b)
      if (.not. rb%lock(3, b)) rb%w(b) = rb%w(b) + dt*rb%force(3, b)/rb%inertia(b)
    end do
  end subroutine rb_impulse

  subroutine rb_walls(rb, g, p, dt, locks)
    !! The closed walls hold the bodies. The domain corner of a particle farthest out towards a wall
    !! is a contact if it would reach the wall within the step; its normal speed after the step must
    !! then be at least -gap / dt (0 once it touches). Projected Gauss-Seidel on the accumulated
    !! normal impulses (>= 0) and the friction impulses (|lambda_t| <= mu lambda_n), with the lever
    !! arm of the corner.
    !! locks = .true. (before the pressure solve): the velocity is left as it was; the contacts are
    !! found for the velocity the body would have with the water's force of the last step (p%aw of
    !! its particles), and a body pressed onto a wall is held along that wall's normal in the solve
    !! (rb%lock; and in rotation when it is pressed on both sides of its centre), so that its push
    !! into the wall is not read as a sink by the water beside it.
    type(rbody_t), intent(inout) :: rb
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    real(wp), intent(in) :: dt
    logical, intent(in) :: locks
    integer(ik) :: b, ip, side, nc, e, sweep
    real(wp) :: n(2), plane, gap, ext, r(2), vn, vt, t(2), rn, rt, kn, kt, dl, lnew, lo, hi, s1, s2
    real(wp) :: xmin(2), xmax(2), vsave(2), wsave, fl(2), mb
    logical :: left, right
    if (rb%n == 0) return
    call grid_box(g, xmin, xmax)
    do b = 1, rb%n
      vsave = rb%v(:, b)
      wsave = rb%w(b)
      if (locks) then   ! the water's force of the last step, per unit mass (the same on every particle)
        fl = 0.0_wp
        mb = 0.0_wp
        do ip = 1, p%n
          if (rb%slot(ip) /= b) cycle
          fl = fl + p%m(ip)*p%aw(:, ip)
          mb = mb + p%m(ip)
        end do
        rb%v(:, b) = rb%v(:, b) + dt*fl/mb
      end if
      nc = 0
      do ip = 1, p%n
        if (rb%slot(ip) /= b) cycle
        do side = 1, 4
          if (g%walls(side) == WALL_OPEN) cycle
          select case (side)
          case (1)
            n = [1.0_wp, 0.0_wp]; plane = xmin(1)
          case (2)
            n = [-1.0_wp, 0.0_wp]; plane = -xmax(1)
          case (3)
            n = [0.0_wp, 1.0_wp]; plane = xmin(2)
          case default
            n = [0.0_wp, -1.0_wp]; plane = -xmax(2)
          end select
          s1 = sign(1.0_wp, dot_product(n, p%r(1:2, ip)))
          s2 = sign(1.0_wp, dot_product(n, p%r(3:4, ip)))
          ext = abs(dot_product(n, p%r(1:2, ip))) + abs(dot_product(n, p%r(3:4, ip)))
          gap = dot_product(n, p%x(:, ip)) - ext - plane
          r = p%x(:, ip) - s1*p%r(1:2, ip) - s2*p%r(3:4, ip) - rb%xc(:, b)   ! the corner, from X
          vn = dot_product(n, rb%v(:, b)) + rb%w(b)*(r(1)*n(2) - r(2)*n(1))
          if (gap + dt*min(vn, 0.0_wp) >= 0.0_wp) cycle
          nc = nc + 1
          rb%cp(nc) = ip
          rb%cn(:, nc) = n
          rb%cr(:, nc) = r
          rb%cmin(nc) = -max(gap, 0.0_wp)/dt
          rb%cl(nc) = 0.0_wp
          rb%ct(nc) = 0.0_wp
        end do
      end do
      if (nc > 0) then
        if (.not. locks) rb%flight(b) = .false.
        do sweep = 1, CONTACT_SWEEPS
          do e = 1, nc
            n = rb%cn(:, e)
            t = [-n(2), n(1)]
            r = rb%cr(:, e)
            rn = r(1)*n(2) - r(2)*n(1)
            rt = r(1)*t(2) - r(2)*t(1)
            kn = 1.0_wp/rb%m(b) + rn**2/rb%inertia(b)
            vn = dot_product(n, rb%v(:, b)) + rb%w(b)*rn
            lnew = max(rb%cl(e) + (rb%cmin(e) - vn)/kn, 0.0_wp)
            dl = lnew - rb%cl(e)
            rb%cl(e) = lnew
            rb%v(:, b) = rb%v(:, b) + dl*n/rb%m(b)
            rb%w(b) = rb%w(b) + dl*rn/rb%inertia(b)
            if (rb%friction(b) > 0.0_wp) then
              kt = 1.0_wp/rb%m(b) + rt**2/rb%inertia(b)
              vt = dot_product(t, rb%v(:, b)) + rb%w(b)*rt
              hi = rb%friction(b)*rb%cl(e)
              lo = -hi
              lnew = min(max(rb%ct(e) - vt/kt, lo), hi)
              dl = lnew - rb%ct(e)
              rb%ct(e) = lnew
              rb%v(:, b) = rb%v(:, b) + dl*t/rb%m(b)
              rb%w(b) = rb%w(b) + dl*rt/rb%inertia(b)
            end if
          end do
        end do
      end if
      if (locks) then
        rb%v(:, b) = vsave
        rb%w(b) = wsave
        do side = 1, 2   ! axis x (walls left, right), y (floor, top)
          left = .false.
          right = .false.
          do e = 1, nc
            if (.not. (rb%cl(e) > 0.0_wp) .or. abs(rb%cn(side, e)) /= 1.0_wp) cycle
            rb%lock(side, b) = .true.
            if (rb%cr(3 - side, e) < 0.0_wp) left = .true.
            if (rb%cr(3 - side, e) > 0.0_wp) right = .true.
          end do
          if (left .and. right) rb%lock(3, b) = .true.
        end do
      end if
    end do
  end subroutine rb_walls

  subroutine rb_move(rb, p, gravity, dt, ke, mom, wg, vmax)
    !! Every body's particles move rigidly over dt with the body's velocity: x = X + dt V + R d,
    !! R the rotation by omega dt, d = x - X; their domains and F turn with R; v = V + omega x (R d).
    !! V is the velocity after the step (symplectic Euler, as the water's particles move), or, for
    !! a body in free flight (no water cell and no wall touched it), the step's mean velocity
    !! (V0 + V) / 2: free fall is then exact, where the velocity after the step put a body 0.6 cm
    !! low after 0.1 s at dt = 0.01 s, and it met the water up to 5 % slower than sqrt(2 g z).
    !! ke, mom, wg: the bodies' kinetic energy, momentum and work of gravity; vmax: the fastest
    !! particle's speed.
    type(rbody_t), intent(in) :: rb
    type(particles_t), intent(inout) :: p
    real(wp), intent(in) :: gravity(2), dt
    real(wp), intent(out) :: ke, mom(2), wg, vmax
    integer(ik) :: ip, b
    real(wp) :: c, s, d(2), xo(2), f(4), rr(4), vt(2)
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    vmax = 0.0_wp
    if (rb%n == 0) return
    do ip = 1, p%n
      b = rb%slot(ip)
      if (b == 0) cycle
      c = cos(rb%w(b)*dt)
      s = sin(rb%w(b)*dt)
      xo = p%x(:, ip)
      d = xo - rb%xc(:, b)
      d = [c*d(1) - s*d(2), s*d(1) + c*d(2)]
      vt = rb%v(:, b)
      if (rb%flight(b)) vt = 0.5_wp*(rb%v0(:, b) + rb%v(:, b))
      p%x(:, ip) = rb%xc(:, b) + dt*vt + d
      p%v(:, ip) = rb%v(:, b) + rb%w(b)*[-d(2), d(1)]
      rr = p%r(:, ip)
      p%r(:, ip) = [c*rr(1) - s*rr(2), s*rr(1) + c*rr(2), c*rr(3) - s*rr(4), s*rr(3) + c*rr(4)]
      f = p%F(:, ip)
      p%F(:, ip) = [c*f(1) - s*f(2), s*f(1) + c*f(2), c*f(3) - s*f(4), s*f(3) + c*f(4)]
      p%L(:, ip) = [0.0_wp, rb%w(b), -rb%w(b), 0.0_wp]
      p%sig(:, ip) = 0.0_wp
      p%psi(ip) = 0.0_wp
      p%vol(ip) = p%vol0(ip)
      p%jbar(ip) = 1.0_wp
      p%aw(:, ip) = rb%force(1:2, b)/rb%m(b)   ! the water's force of this step: next step's wall locks
      ke = ke + 0.5_wp*p%m(ip)*(p%v(1, ip)**2 + p%v(2, ip)**2)
      mom = mom + p%m(ip)*p%v(:, ip)
      wg = wg + p%m(ip)*dot_product(gravity, p%x(:, ip) - xo)
      vmax = max(vmax, abs(p%v(1, ip)), abs(p%v(2, ip)))
    end do
  end subroutine rb_move
end module cpdi_rigid_body
