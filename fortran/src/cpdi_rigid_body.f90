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
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC, CPDI_ERR_INPUT
  use cpdi_particles, only: particles_t
  use cpdi_grid, only: grid_t, WALL_OPEN
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
    real(wp), allocatable :: force(:, :)         !! (3, n): the water's force and torque of the last step
    real(wp), allocatable :: uvb(:, :), vvb(:, :) !! per body: its volume on the u and v face lattices
    integer(ik), allocatable :: cp(:)            !! contact candidates (particles)
    real(wp), allocatable :: cn(:, :), cl(:), ct(:), cmin(:)   !! their normal, impulses, target speed
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
                                         rb%force, rb%v0, rb%flight, rb%uvb, rb%vvb, rb%cp, rb%cn, rb%cl, rb%ct, rb%cmin)
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
              rb%force(3, rb%n), rb%uvb(nnodes, rb%n), rb%vvb(nnodes, rb%n), rb%cp(npart), rb%cn(2, npart), &
              rb%cl(npart), rb%ct(npart), rb%cmin(npart), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the rigid bodies; use a larger cell size')
      return
    end if
    rb%m = 0.0_wp; rb%inertia = 0.0_wp; rb%xc = 0.0_wp; rb%v = 0.0_wp; rb%w = 0.0_wp; rb%force = 0.0_wp
    rb%uvb = 0.0_wp; rb%vvb = 0.0_wp
    rb%friction = 0.0_wp
    do ip = 1, p%n
      if (rb%slot(ip) /= 0) rb%friction(rb%slot(ip)) = friction(p%mat(ip))
    end do
    do ip = 1, rb%n
      if (.not. (rb%friction(ip) >= 0.0_wp)) then
        call st%set(CPDI_ERR_INPUT, 'a rigid_body friction coefficient must be >= 0')
        return
      end if
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
    mom = 0.0_wp
    fb = 0.0_wp
    do ip = 1, p%n
      b = rb%slot(ip)
      if (b == 0) cycle
      mp = p%m(ip)
      rb%m(b) = rb%m(b) + mp
      rb%vol(b) = rb%vol(b) + p%vol(ip)
      rb%xc(:, b) = rb%xc(:, b) + mp*p%x(:, ip)
      mom(:, b) = mom(:, b) + mp*p%v(:, ip)
      fb(:, b) = fb(:, b) + mp*p%bf(:, ip)
    end do
    do b = 1, rb%n
      rb%xc(:, b) = rb%xc(:, b)/rb%m(b)
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
    end do
    ! the body's volume and its centroid on each face lattice (u faces i = lo..hi+1 at cell-centre
    ! height, v faces j = lo..hi+1 at cell-centre abscissa)
    su = 0.0_wp
    sv = 0.0_wp
    yu = 0.0_wp
    xv = 0.0_wp
    do j = mc%lo(2), mc%hi(2) + 1
      do i = mc%lo(1), mc%hi(1) + 1
        c = i + (j - 1)*n1
        xc = g%gorig + ([real(i, wp), real(j, wp)] - 0.5_wp)*g%h
        do b = 1, rb%n
          if (j <= mc%hi(2)) then
            a = frac(c, wu, uvs, rb%uvb(:, b))
            su(b) = su(b) + a
            yu(b) = yu(b) + a*xc(2)
          end if
          if (i <= mc%hi(1)) then
            a = frac(c, wv, vvs, rb%vvb(:, b))
            sv(b) = sv(b) + a
            xv(b) = xv(b) + a*xc(1)
          end if
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
          jc = mc%h*[gx, gy, gy*(xc(1) - xv(b)) - gx*(xc(2) - yu(b))]
          mc%nlr = mc%nlr + 1
          mc%lrc(mc%nlr) = c
          mc%lrb(mc%nlr) = b
          mc%lrj(:, mc%nlr) = jc
          rb%flight(b) = .false.
          mc%b(c) = mc%b(c) - (rho/dt)*(jc(1)*rb%v(1, b) + jc(2)*rb%v(2, b) + jc(3)*rb%w(b))
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
    do b = 1, rb%n
      rb%v(:, b) = rb%v(:, b) + dt*rb%force(1:2, b)/rb%m(b)
      rb%w(b) = rb%w(b) + dt*rb%force(3, b)/rb%inertia(b)
    end do
  end subroutine rb_impulse

  subroutine rb_walls(rb, g, p, dt)
    !! The closed walls hold the bodies. A particle's domain corner farthest out towards a wall is
    !! a contact if it would reach the wall within the step; its normal speed after the step must
    !! then be at least -gap / dt (0 once it touches). Projected Gauss-Seidel on the accumulated
    !! normal impulses (>= 0) and the friction impulses (|lambda_t| <= mu lambda_n).
    type(rbody_t), intent(inout) :: rb
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    real(wp), intent(in) :: dt
    integer(ik) :: b, ip, side, nc, e, sweep
    real(wp) :: n(2), plane, gap, ext, r(2), vn, vt, t(2), rn, rt, kn, kt, dl, lnew, lo, hi
    real(wp) :: xmin(2), xmax(2)
    if (rb%n == 0) return
    xmin = g%origin
    xmax = g%origin + real(g%ncell, wp)*g%h
    do b = 1, rb%n
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
          ext = abs(dot_product(n, p%r(1:2, ip))) + abs(dot_product(n, p%r(3:4, ip)))
          gap = dot_product(n, p%x(:, ip)) - ext - plane
          r = p%x(:, ip) - rb%xc(:, b)
          vn = dot_product(n, rb%v(:, b)) + rb%w(b)*(r(1)*n(2) - r(2)*n(1))
          if (gap + dt*min(vn, 0.0_wp) >= 0.0_wp) cycle
          nc = nc + 1
          rb%cp(nc) = ip
          rb%cn(:, nc) = n
          rb%cmin(nc) = -max(gap, 0.0_wp)/dt
          rb%cl(nc) = 0.0_wp
          rb%ct(nc) = 0.0_wp
        end do
      end do
      if (nc == 0) cycle
      rb%flight(b) = .false.
      do sweep = 1, CONTACT_SWEEPS
        do e = 1, nc
          n = rb%cn(:, e)
          t = [-n(2), n(1)]
          r = p%x(:, rb%cp(e)) - rb%xc(:, b)
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
      ke = ke + 0.5_wp*p%m(ip)*(p%v(1, ip)**2 + p%v(2, ip)**2)
      mom = mom + p%m(ip)*p%v(:, ip)
      wg = wg + p%m(ip)*dot_product(gravity, p%x(:, ip) - xo)
      vmax = max(vmax, abs(p%v(1, ip)), abs(p%v(2, ip)))
    end do
  end subroutine rb_move
end module cpdi_rigid_body
