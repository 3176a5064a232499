!> Particle-to-grid interpolation weights: linear MPM, uGIMP and CPDI1.
module cpdi_shape
  !! For every particle p this fills `ns` slots (node index, weight S_ip, gradient
  !! grad S_ip); `cnt(p)` of them are in use. For CPDI the 16 corner-node pairs are
  !! merged into the 3x3 node block when the four corners lie in a 2x2-cell block (the
  !! usual case), so most CPDI particles use 9 slots; a domain spanning more cells keeps
  !! 16 slots, in which a node may appear twice (scatters and gathers add them: exact).
  !!
  !! * MPM: bilinear N_i(x_p), 4 slots.
  !! * uGIMP: tensor product of the 1D GIMP function with the initial half-widths
  !!   (Bardenhagen & Kober 2004), 9 slots; needs half-widths <= h/2.
  !! * CPDI1: parallelogram domain spanned by r1, r2 (Sadeghirad et al. 2011),
  !!   S_ip = 1/4 sum_c N_i(x_c), 16 slots (FORMULAS 4.1).
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  use cpdi_grid, only: grid_t
  use cpdi_particles, only: particles_t
  implicit none
  private

  integer(ik), parameter, public :: SHAPE_MPM = 0
  integer(ik), parameter, public :: SHAPE_GIMP = 1
  integer(ik), parameter, public :: SHAPE_CPDI = 2

  integer(ik), parameter, public :: SHAPE_FAIL_NONE = 0      !! no failure
  integer(ik), parameter, public :: SHAPE_FAIL_OUTSIDE = 1   !! support beyond the padded grid
  integer(ik), parameter, public :: SHAPE_FAIL_INVERTED = 2  !! CPDI domain with r1 x r2 <= 0

  type, public :: shape_t
    !! Connectivity and weights of all particles, `(ns, n)` each.
    integer(ik) :: kind = SHAPE_MPM
    integer(ik) :: ns = 4
    integer(ik), allocatable :: idx(:, :)
    integer(ik), allocatable :: cnt(:)     !! slots in use per particle
    real(wp), allocatable :: w(:, :), gx(:, :), gy(:, :)
  end type shape_t

  public :: shape_slots, shape_alloc, shape_compute, gimp_1d

contains

  pure integer(ik) function shape_slots(kind)
    !! Number of slots per particle for an interpolation kind.
    integer(ik), intent(in) :: kind
    select case (kind)
    case (SHAPE_GIMP)
      shape_slots = 9
    case (SHAPE_CPDI)
      shape_slots = 16
    case default
      shape_slots = 4
    end select
  end function shape_slots

  subroutine shape_alloc(sh, kind, n, st)
    !! Allocate slot storage for n particles.
    type(shape_t), intent(inout) :: sh
    integer(ik), intent(in) :: kind, n
    type(status_t), intent(inout) :: st
    integer :: ierr
    sh%kind = kind
    sh%ns = shape_slots(kind)
    if (allocated(sh%idx)) deallocate (sh%idx, sh%cnt, sh%w, sh%gx, sh%gy)
    allocate (sh%idx(sh%ns, n), sh%cnt(n), sh%w(sh%ns, n), sh%gx(sh%ns, n), sh%gy(sh%ns, n), stat=ierr)
    if (ierr == 0) sh%cnt = sh%ns
    if (ierr /= 0) call st%set(CPDI_ERR_ALLOC, 'could not allocate interpolation storage; use fewer particles')
  end subroutine shape_alloc

  pure subroutine gimp_1d(d, lp, h, s, ds)
    !! 1D uGIMP function and derivative for particle-node distance d = x_p - x_i,
    !! particle half-width lp (<= h/2) and cell size h.
    real(wp), intent(in) :: d, lp, h
    real(wp), intent(out) :: s, ds
    real(wp) :: a
    a = abs(d)
    if (a < lp) then
      s = 1.0_wp - (d*d + lp*lp)/(2.0_wp*h*lp)
      ds = -d/(h*lp)
    else if (a <= h - lp) then
      s = 1.0_wp - a/h
      ds = -sign(1.0_wp, d)/h
    else if (a < h + lp) then
      s = (h + lp - a)**2/(4.0_wp*h*lp)
      ds = -sign(1.0_wp, d)*(h + lp - a)/(2.0_wp*h*lp)
    else
      s = 0.0_wp
      ds = 0.0_wp
    end if
  end subroutine gimp_1d

  pure subroutine bilinear(g, x, k, nvals, ok)
    !! Node indices and bilinear values at point x; ok = .false. if outside the grid.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik), intent(out) :: k(4)
    real(wp), intent(out) :: nvals(4)
    logical, intent(out) :: ok
    real(wp) :: s1, s2, xi, eta
    integer(ik) :: i0, j0, base
    s1 = (x(1) - g%gorig(1))/g%h
    s2 = (x(2) - g%gorig(2))/g%h
    ok = s1 >= 0.0_wp .and. s2 >= 0.0_wp .and. s1 < real(g%nn(1) - 1, wp) .and. s2 < real(g%nn(2) - 1, wp)
    if (.not. ok) then
      k = 1
      nvals = 0.0_wp
      return
    end if
    i0 = int(s1, ik)
    j0 = int(s2, ik)
    xi = s1 - real(i0, wp)
    eta = s2 - real(j0, wp)
    base = i0 + 1 + j0*g%nn(1)
    k = [base, base + 1, base + g%nn(1), base + g%nn(1) + 1]
    nvals = [(1.0_wp - xi)*(1.0_wp - eta), xi*(1.0_wp - eta), (1.0_wp - xi)*eta, xi*eta]
  end subroutine bilinear

  pure subroutine shape_mpm_one(g, x, k, w, gx, gy, fail)
    !! Linear MPM weights at one particle.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik), intent(out) :: k(4)
    real(wp), intent(out) :: w(4), gx(4), gy(4)
    integer(ik), intent(out) :: fail
    real(wp) :: xi, eta, rh
    logical :: ok
    call bilinear(g, x, k, w, ok)
    fail = SHAPE_FAIL_NONE
    if (.not. ok) then
      fail = SHAPE_FAIL_OUTSIDE
      gx = 0.0_wp
      gy = 0.0_wp
      return
    end if
    rh = 1.0_wp/g%h
    xi = (x(1) - g%gorig(1))*rh
    xi = xi - aint(xi)
    eta = (x(2) - g%gorig(2))*rh
    eta = eta - aint(eta)
    gx = [-(1.0_wp - eta), (1.0_wp - eta), -eta, eta]*rh
    gy = [-(1.0_wp - xi), -xi, (1.0_wp - xi), xi]*rh
  end subroutine shape_mpm_one

  pure subroutine shape_gimp_one(g, x, lp, k, w, gx, gy, fail)
    !! uGIMP weights at one particle with half-widths lp(2).
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2), lp(2)
    integer(ik), intent(out) :: k(9)
    real(wp), intent(out) :: w(9), gx(9), gy(9)
    integer(ik), intent(out) :: fail
    real(wp) :: sx(3), dsx(3), sy(3), dsy(3), s1, s2
    integer(ik) :: ci, cj, a, b, slot
    s1 = (x(1) - g%gorig(1))/g%h
    s2 = (x(2) - g%gorig(2))/g%h
    fail = SHAPE_FAIL_NONE
    if (.not. (s1 >= 1.0_wp .and. s2 >= 1.0_wp .and. s1 < real(g%nn(1) - 2, wp) &
               .and. s2 < real(g%nn(2) - 2, wp))) then
      fail = SHAPE_FAIL_OUTSIDE
      k = 1
      w = 0.0_wp
      gx = 0.0_wp
      gy = 0.0_wp
      return
    end if
    ci = nint(s1, ik)   ! nearest node, 0-based
    cj = nint(s2, ik)
    do a = 1, 3
      call gimp_1d(x(1) - (g%gorig(1) + real(ci + a - 2, wp)*g%h), lp(1), g%h, sx(a), dsx(a))
      call gimp_1d(x(2) - (g%gorig(2) + real(cj + a - 2, wp)*g%h), lp(2), g%h, sy(a), dsy(a))
    end do
    slot = 0
    do b = 1, 3
      do a = 1, 3
        slot = slot + 1
        k(slot) = (ci + a - 1) + (cj + b - 2)*g%nn(1)
        w(slot) = sx(a)*sy(b)
        gx(slot) = dsx(a)*sy(b)
        gy(slot) = sx(a)*dsy(b)
      end do
    end do
  end subroutine shape_gimp_one

  pure subroutine shape_cpdi_one(g, x, r, k, w, gx, gy, cnt, fail)
    !! CPDI1 weights at one particle with domain vectors r = [r1x, r1y, r2x, r2y].
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2), r(4)
    integer(ik), intent(out) :: k(16)
    real(wp), intent(out) :: w(16), gx(16), gy(16)
    integer(ik), intent(out) :: cnt, fail
    real(wp) :: cross, rv, xc(2, 4), gc(2, 4), nv(4, 4), ga(2), gb(2)
    integer(ik) :: c, kk(4, 4), s0, i0(4), j0(4), bi, bj, a, li, lj, base
    logical :: ok, inside
    fail = SHAPE_FAIL_NONE
    cnt = 16
    cross = r(1)*r(4) - r(2)*r(3)
    if (.not. (cross > 0.0_wp)) then
      fail = SHAPE_FAIL_INVERTED
      k = 1
      w = 0.0_wp
      gx = 0.0_wp
      gy = 0.0_wp
      return
    end if
    rv = 1.0_wp/(4.0_wp*cross)              ! 1 / V_p
    ga = [r(2) - r(4), r(3) - r(1)]*rv      ! multiplies N(x1) - N(x3)
    gb = [r(2) + r(4), -r(1) - r(3)]*rv     ! multiplies N(x2) - N(x4)
    xc(:, 1) = [x(1) - r(1) - r(3), x(2) - r(2) - r(4)]
    xc(:, 2) = [x(1) + r(1) - r(3), x(2) + r(2) - r(4)]
    xc(:, 3) = [x(1) + r(1) + r(3), x(2) + r(2) + r(4)]
    xc(:, 4) = [x(1) - r(1) + r(3), x(2) - r(2) + r(4)]
    gc(:, 1) = ga
    gc(:, 2) = gb
    gc(:, 3) = -ga
    gc(:, 4) = -gb
    inside = .true.
    do c = 1, 4
      call bilinear(g, xc(:, c), kk(:, c), nv(:, c), ok)
      if (.not. ok) then
        fail = SHAPE_FAIL_OUTSIDE
        inside = .false.
      end if
      i0(c) = mod(kk(1, c) - 1, g%nn(1))     ! 0-based lower-left node of the corner's cell
      j0(c) = (kk(1, c) - 1)/g%nn(1)
    end do
    bi = minval(i0)
    bj = minval(j0)
    if (inside .and. maxval(i0) - bi <= 1 .and. maxval(j0) - bj <= 1) then
      ! all corners in a 2x2-cell block: merge into the 3x3 node stencil
      cnt = 9
      w(1:9) = 0.0_wp
      gx(1:9) = 0.0_wp
      gy(1:9) = 0.0_wp
      base = bi + 1 + bj*g%nn(1)
      do lj = 0, 2
        do li = 0, 2
          k(1 + li + 3*lj) = base + li + lj*g%nn(1)
        end do
      end do
      do c = 1, 4
        do a = 1, 4
          li = i0(c) - bi + mod(a - 1, 2)
          lj = j0(c) - bj + (a - 1)/2
          s0 = 1 + li + 3*lj
          w(s0) = w(s0) + 0.25_wp*nv(a, c)
          gx(s0) = gx(s0) + nv(a, c)*gc(1, c)
          gy(s0) = gy(s0) + nv(a, c)*gc(2, c)
        end do
      end do
    else
      do c = 1, 4
        s0 = 4*(c - 1)
        k(s0 + 1:s0 + 4) = kk(:, c)
        w(s0 + 1:s0 + 4) = 0.25_wp*nv(:, c)
        gx(s0 + 1:s0 + 4) = nv(:, c)*gc(1, c)
        gy(s0 + 1:s0 + 4) = nv(:, c)*gc(2, c)
      end do
    end if
  end subroutine shape_cpdi_one

  subroutine shape_compute(g, p, sh, bad, fail)
    !! Weights of every particle. On failure, `bad` is the first failing particle and
    !! `fail` its SHAPE_FAIL_* cause; otherwise bad = 0.
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    type(shape_t), intent(inout) :: sh
    integer(ik), intent(out) :: bad, fail
    integer(ik) :: ip, f
    real(wp) :: lp(2)
    bad = 0
    fail = SHAPE_FAIL_NONE
    select case (sh%kind)
    case (SHAPE_GIMP)
      do ip = 1, p%n
        lp = [abs(p%r0(1, ip)) + abs(p%r0(3, ip)), abs(p%r0(2, ip)) + abs(p%r0(4, ip))]
        call shape_gimp_one(g, p%x(:, ip), lp, sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), sh%gy(:, ip), f)
        if (f /= SHAPE_FAIL_NONE .and. bad == 0) then
          bad = ip
          fail = f
        end if
      end do
    case (SHAPE_CPDI)
      do ip = 1, p%n
        call shape_cpdi_one(g, p%x(:, ip), p%r(:, ip), sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), sh%gy(:, ip), &
                            sh%cnt(ip), f)
        if (f /= SHAPE_FAIL_NONE .and. bad == 0) then
          bad = ip
          fail = f
        end if
      end do
    case default
      do ip = 1, p%n
        call shape_mpm_one(g, p%x(:, ip), sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), sh%gy(:, ip), f)
        if (f /= SHAPE_FAIL_NONE .and. bad == 0) then
          bad = ip
          fail = f
        end if
      end do
    end select
  end subroutine shape_compute
end module cpdi_shape
