!> Particle-to-grid interpolation weights: linear MPM, uGIMP and CPDI1.
module cpdi_shape
  !! For every particle p this fills up to `ns` slots (node index, weight S_ip, gradient
  !! grad S_ip). For CPDI the 16 corner-node pairs are merged into the 3x3 node block when
  !! the four corners lie in a 2x2-cell block (the usual case), so most CPDI particles use 9
  !! slots; a domain spanning more cells keeps 16 slots, in which a node may appear twice
  !! (scatters and gathers add them: exact).
  !!
  !! Storage: every particle has `nm` main slots (`idx`, `w`, `gx`, `gy`, `(nm, n)`); the
  !! slots nm+1..ns of the few particles that need them (CPDI: slots 10..16) live in an
  !! overflow pool (`pidx`, `pw`, `pgx`, `pgy`, `(ns - nm, capacity)`), column `ovf(p)`
  !! (0: none). A particle's slots are main 1..nm, then pool 1..ns-nm, and every consumer
  !! visits them in that order (the summation order of one 16-slot array). This keeps the
  !! interpolation at 260 B per CPDI particle instead of 456 B. The pool is filled per
  !! fixed particle block (count, prefix sum, fill: its columns follow particle order at any
  !! thread count) and grows geometrically, only when its capacity is exceeded.
  !!
  !! * MPM: bilinear N_i(x_p), 4 slots.
  !! * uGIMP: tensor product of the 1D GIMP function with the initial half-widths
  !!   (Bardenhagen & Kober 2004), 9 slots; needs half-widths <= h/2.
  !! * CPDI1: parallelogram domain spanned by r1, r2 (Sadeghirad et al. 2011),
  !!   S_ip = 1/4 sum_c N_i(x_c), 16 slots (FORMULAS 4.1), 9 of them main.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  use cpdi_grid, only: grid_t
  use cpdi_particles, only: particles_t
  use cpdi_schedule, only: NCHUNK, chunk_range
  implicit none
  private

  integer(ik), parameter, public :: SHAPE_MPM = 0
  integer(ik), parameter, public :: SHAPE_GIMP = 1
  integer(ik), parameter, public :: SHAPE_CPDI = 2

  integer(ik), parameter, public :: SHAPE_FAIL_NONE = 0      !! no failure
  integer(ik), parameter, public :: SHAPE_FAIL_OUTSIDE = 1   !! support beyond the padded grid
  integer(ik), parameter, public :: SHAPE_FAIL_INVERTED = 2  !! CPDI domain with r1 x r2 <= 0

  type, public :: shape_t
    !! Connectivity and weights of all particles: `nm` main slots each, `(nm, n)`, and the
    !! overflow pool of slots nm+1..ns, `(ns - nm, capacity)`.
    integer(ik) :: kind = SHAPE_MPM
    integer(ik) :: ns = 4                  !! most slots of one particle
    integer(ik) :: nm = 4                  !! main slots of every particle
    integer(ik), allocatable :: idx(:, :)
    integer(ik), allocatable :: ovf(:)     !! pool column of slots nm+1..ns per particle (0: none)
    integer(ik), allocatable :: row(:)     !! lowest node row of each stencil (0-based)
    integer(ik) :: span = 1                !! tallest stencil: last minus first node row
    real(wp), allocatable :: w(:, :), gx(:, :), gy(:, :)
    integer(ik), allocatable :: pidx(:, :)            !! overflow pool: node indices
    real(wp), allocatable :: pw(:, :), pgx(:, :), pgy(:, :)  !! overflow pool: weights, gradients
  end type shape_t

  public :: shape_slots, shape_alloc, shape_compute, shape_count, shape_slot, gimp_1d

contains

  pure integer(ik) function shape_slots(kind)
    !! Most slots of one particle for an interpolation kind.
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

  pure integer(ik) function main_slots(kind)
    !! Slots stored for every particle (the rest go to the overflow pool).
    integer(ik), intent(in) :: kind
    main_slots = min(shape_slots(kind), 9_ik)
  end function main_slots

  subroutine shape_alloc(sh, kind, n, st)
    !! Allocate slot storage for n particles (an empty overflow pool).
    type(shape_t), intent(inout) :: sh
    integer(ik), intent(in) :: kind, n
    type(status_t), intent(inout) :: st
    integer :: ierr
    sh%kind = kind
    sh%ns = shape_slots(kind)
    sh%nm = main_slots(kind)
    if (allocated(sh%idx)) deallocate (sh%idx, sh%ovf, sh%row, sh%w, sh%gx, sh%gy)
    allocate (sh%idx(sh%nm, n), sh%ovf(n), sh%row(n), sh%w(sh%nm, n), sh%gx(sh%nm, n), sh%gy(sh%nm, n), &
              stat=ierr)
    if (ierr == 0) then
      sh%ovf = 0
      sh%row = 0
      call pool_reserve(sh, 0_ik, ierr)
    end if
    if (ierr /= 0) call st%set(CPDI_ERR_ALLOC, 'could not allocate interpolation storage; use fewer particles')
  end subroutine shape_alloc

  subroutine pool_reserve(sh, need, ierr)
    !! Make room for `need` overflow columns: kept if it fits, else reallocated (contents
    !! dropped, shape_compute refills them) to max(need, twice the old capacity).
    type(shape_t), intent(inout) :: sh
    integer(ik), intent(in) :: need
    integer, intent(out) :: ierr
    integer(ik) :: cap
    ierr = 0
    cap = 0
    if (allocated(sh%pidx)) then
      cap = size(sh%pidx, 2, kind=ik)
      if (need <= cap) return
      deallocate (sh%pidx, sh%pw, sh%pgx, sh%pgy)
    end if
    if (need > 0) cap = min(max(need, 2*cap, 64_ik), max(need, size(sh%ovf, kind=ik)))
    allocate (sh%pidx(sh%ns - sh%nm, cap), sh%pw(sh%ns - sh%nm, cap), sh%pgx(sh%ns - sh%nm, cap), &
              sh%pgy(sh%ns - sh%nm, cap), stat=ierr)
    if (ierr /= 0) then   ! leave an empty pool behind, never an unallocated one
      if (allocated(sh%pidx)) deallocate (sh%pidx)
      if (allocated(sh%pw)) deallocate (sh%pw)
      if (allocated(sh%pgx)) deallocate (sh%pgx)
      if (allocated(sh%pgy)) deallocate (sh%pgy)
      allocate (sh%pidx(sh%ns - sh%nm, 0), sh%pw(sh%ns - sh%nm, 0), sh%pgx(sh%ns - sh%nm, 0), &
                sh%pgy(sh%ns - sh%nm, 0))
    end if
  end subroutine pool_reserve

  pure integer(ik) function shape_count(sh, ip)
    !! Slots in use by particle ip.
    type(shape_t), intent(in) :: sh
    integer(ik), intent(in) :: ip
    shape_count = sh%nm
    if (sh%ovf(ip) /= 0) shape_count = sh%ns
  end function shape_count

  pure subroutine shape_slot(sh, ip, a, k, w, gx, gy)
    !! Slot a (1..shape_count) of particle ip: main slot a, or pool slot a - nm.
    type(shape_t), intent(in) :: sh
    integer(ik), intent(in) :: ip, a
    integer(ik), intent(out) :: k
    real(wp), intent(out) :: w, gx, gy
    if (a <= sh%nm) then
      k = sh%idx(a, ip)
      w = sh%w(a, ip)
      gx = sh%gx(a, ip)
      gy = sh%gy(a, ip)
    else
      k = sh%pidx(a - sh%nm, sh%ovf(ip))
      w = sh%pw(a - sh%nm, sh%ovf(ip))
      gx = sh%pgx(a - sh%nm, sh%ovf(ip))
      gy = sh%pgy(a - sh%nm, sh%ovf(ip))
    end if
  end subroutine shape_slot

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

  pure subroutine shape_mpm_one(g, x, k, w, gx, gy, c0, fail)
    !! Linear MPM weights at one particle; c0 is the stencil's first node row.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik), intent(out) :: k(4)
    real(wp), intent(out) :: w(4), gx(4), gy(4)
    integer(ik), intent(out) :: c0, fail
    real(wp) :: xi, eta, rh
    logical :: ok
    call bilinear(g, x, k, w, ok)
    fail = SHAPE_FAIL_NONE
    c0 = 0
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
    c0 = (k(1) - 1)/g%nn(1)      ! exactly the row bilinear chose
    eta = eta - aint(eta)
    gx = [-(1.0_wp - eta), (1.0_wp - eta), -eta, eta]*rh
    gy = [-(1.0_wp - xi), -xi, (1.0_wp - xi), xi]*rh
  end subroutine shape_mpm_one

  pure subroutine shape_gimp_one(g, x, lp, k, w, gx, gy, c0, fail)
    !! uGIMP weights at one particle with half-widths lp(2); c0 is the stencil's first
    !! node row.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2), lp(2)
    integer(ik), intent(out) :: k(9)
    real(wp), intent(out) :: w(9), gx(9), gy(9)
    integer(ik), intent(out) :: c0, fail
    real(wp) :: sx(3), dsx(3), sy(3), dsy(3), s1, s2
    integer(ik) :: ci, cj, a, b, slot
    s1 = (x(1) - g%gorig(1))/g%h
    s2 = (x(2) - g%gorig(2))/g%h
    fail = SHAPE_FAIL_NONE
    c0 = 0
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
    c0 = cj - 1
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

  pure subroutine shape_cpdi_one(g, x, r, k, w, gx, gy, ko, wo, gxo, gyo, cnt, c0, span, fail)
    !! CPDI1 weights at one particle with domain vectors r = [r1x, r1y, r2x, r2y]: slots
    !! 1..9 in k, w, gx, gy, slots 10..16 (if cnt = 16) in ko, wo, gxo, gyo; c0 and span are
    !! the first node row of the stencil and its height minus one.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2), r(4)
    integer(ik), intent(out) :: k(9), ko(7)
    real(wp), intent(out) :: w(9), gx(9), gy(9), wo(7), gxo(7), gyo(7)
    integer(ik), intent(out) :: cnt, c0, span, fail
    real(wp) :: cross, rv, xc(2, 4), gc(2, 4), nv(4), ga(2), gb(2), rh, su(4), sv(4), u, v
    real(wp) :: hx(3, 4), hy(3, 4), p1, p2, p3, p4, w16(16), gx16(16), gy16(16)
    integer(ik) :: c, s0, i0(4), j0(4), bi, bj, li, lj, a, base, nn1, k16(16)
    fail = SHAPE_FAIL_NONE
    cnt = 16
    c0 = 0
    span = 1
    cross = r(1)*r(4) - r(2)*r(3)
    if (.not. (cross > 0.0_wp)) then
      fail = SHAPE_FAIL_INVERTED
      call clear(k, w, gx, gy)
      call clear(ko, wo, gxo, gyo)
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
    rh = 1.0_wp/g%h
    nn1 = g%nn(1)
    ! corner cells, with no integer division (this is the hot path)
    do c = 1, 4
      su(c) = (xc(1, c) - g%gorig(1))*rh
      sv(c) = (xc(2, c) - g%gorig(2))*rh
      if (.not. (su(c) >= 0.0_wp .and. sv(c) >= 0.0_wp .and. su(c) < real(nn1 - 1, wp) &
                 .and. sv(c) < real(g%nn(2) - 1, wp))) then
        fail = SHAPE_FAIL_OUTSIDE
        call clear(k, w, gx, gy)
        call clear(ko, wo, gxo, gyo)
        return
      end if
      i0(c) = int(su(c), ik)
      j0(c) = int(sv(c), ik)
    end do
    bi = min(i0(1), i0(2), i0(3), i0(4))
    bj = min(j0(1), j0(2), j0(3), j0(4))
    c0 = bj
    span = max(j0(1), j0(2), j0(3), j0(4)) + 1 - bj
    if (span <= 2 .and. max(i0(1), i0(2), i0(3), i0(4)) - bi <= 1) then
      ! All corners in a 2x2-cell block: merge into the 3x3 node stencil. Corner c's
      ! bilinear values there are the outer product P_c = X_c (x) Y_c of the 1D hats
      ! X(l) = max(0, 1 - |u - l|), u = its local coordinate in [0, 2), and likewise Y:
      ! w = (P1 + P2 + P3 + P4)/4 and, as g3 = -g1 and g4 = -g2,
      ! grad = g1 (P1 - P3) + g2 (P2 - P4): a fixed 9-node loop with no indexing.
      cnt = 9
      base = bi + 1 + bj*nn1
      do c = 1, 4
        u = su(c) - real(bi, wp)
        v = sv(c) - real(bj, wp)
        hx(1, c) = max(0.0_wp, 1.0_wp - u)
        hx(2, c) = max(0.0_wp, 1.0_wp - abs(u - 1.0_wp))
        hx(3, c) = max(0.0_wp, u - 1.0_wp)
        hy(1, c) = max(0.0_wp, 1.0_wp - v)
        hy(2, c) = max(0.0_wp, 1.0_wp - abs(v - 1.0_wp))
        hy(3, c) = max(0.0_wp, v - 1.0_wp)
      end do
      do lj = 1, 3
        do li = 1, 3
          a = li + 3*lj - 3
          k(a) = base + (li - 1) + (lj - 1)*nn1
          p1 = hx(li, 1)*hy(lj, 1)
          p2 = hx(li, 2)*hy(lj, 2)
          p3 = hx(li, 3)*hy(lj, 3)
          p4 = hx(li, 4)*hy(lj, 4)
          w(a) = 0.25_wp*((p1 + p2) + (p3 + p4))
          gx(a) = ga(1)*(p1 - p3) + gb(1)*(p2 - p4)
          gy(a) = ga(2)*(p1 - p3) + gb(2)*(p2 - p4)
        end do
      end do
    else
      do c = 1, 4
        u = su(c) - real(i0(c), wp)
        v = sv(c) - real(j0(c), wp)
        nv = [(1.0_wp - u)*(1.0_wp - v), u*(1.0_wp - v), (1.0_wp - u)*v, u*v]
        s0 = 4*(c - 1)
        base = i0(c) + 1 + j0(c)*nn1
        k16(s0 + 1:s0 + 4) = [base, base + 1, base + nn1, base + nn1 + 1]
        w16(s0 + 1:s0 + 4) = 0.25_wp*nv
        gx16(s0 + 1:s0 + 4) = nv*gc(1, c)
        gy16(s0 + 1:s0 + 4) = nv*gc(2, c)
      end do
      k = k16(1:9)
      w = w16(1:9)
      gx = gx16(1:9)
      gy = gy16(1:9)
      ko = k16(10:16)
      wo = w16(10:16)
      gxo = gx16(10:16)
      gyo = gy16(10:16)
    end if
  end subroutine shape_cpdi_one

  pure subroutine clear(k, w, gx, gy)
    !! Neutral slots of a particle whose weights could not be formed.
    integer(ik), intent(out) :: k(:)
    real(wp), intent(out) :: w(:), gx(:), gy(:)
    k = 1
    w = 0.0_wp
    gx = 0.0_wp
    gy = 0.0_wp
  end subroutine clear

  subroutine shape_compute(g, p, sh, bad, fail, st)
    !! Weights of every particle (OpenMP over fixed particle blocks). On failure, `bad` is
    !! the lowest failing particle and `fail` its SHAPE_FAIL_* cause; otherwise bad = 0.
    !! Also sets each stencil's first node row and the tallest span (for the strips).
    !! CPDI particles that need slots 10..16 are counted per block in the first pass; after
    !! a prefix sum over the blocks (and growing the pool if it is too small: st reports an
    !! allocation failure) the second pass recomputes just those particles into their pool
    !! columns, which follow particle order.
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    type(shape_t), intent(inout) :: sh
    integer(ik), intent(out) :: bad, fail
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, f, c, lo, hi, span, sp, nc, j, cbad(NCHUNK), cfail(NCHUNK), cnov(NCHUNK), col(NCHUNK)
    integer(ik) :: ko(7), k9(9), r9
    real(wp) :: lp(2), wo(7), gxo(7), gyo(7), w9(9), gx9(9), gy9(9)
    integer :: ierr
    span = 1
    cbad = 0
    cfail = SHAPE_FAIL_NONE
    cnov = 0
    !$omp parallel do schedule(static) default(shared) private(c, lo, hi, ip, f, sp, lp, nc, ko, wo, gxo, gyo) &
    !$omp reduction(max:span)
    do c = 1, NCHUNK
      call chunk_range(c, p%n, lo, hi)
      do ip = lo, hi
        select case (sh%kind)
        case (SHAPE_CPDI)
          call shape_cpdi_one(g, p%x(:, ip), p%r(:, ip), sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), &
                              sh%gy(:, ip), ko, wo, gxo, gyo, nc, sh%row(ip), sp, f)
          sh%ovf(ip) = 0
          if (nc > sh%nm .and. f == SHAPE_FAIL_NONE) then   ! a pool column, numbered below
            sh%ovf(ip) = -1
            cnov(c) = cnov(c) + 1
          end if
        case (SHAPE_GIMP)
          lp = [abs(p%r0(1, ip)) + abs(p%r0(3, ip)), abs(p%r0(2, ip)) + abs(p%r0(4, ip))]
          call shape_gimp_one(g, p%x(:, ip), lp, sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), sh%gy(:, ip), &
                              sh%row(ip), f)
          sp = 2
        case default
          call shape_mpm_one(g, p%x(:, ip), sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), sh%gy(:, ip), &
                             sh%row(ip), f)
          sp = 1
        end select
        span = max(span, sp)
        if (f /= SHAPE_FAIL_NONE .and. cbad(c) == 0) then
          cbad(c) = ip
          cfail(c) = f
        end if
      end do
    end do
    !$omp end parallel do
    sh%span = span
    bad = 0
    fail = SHAPE_FAIL_NONE
    do c = 1, NCHUNK
      if (cbad(c) /= 0) then
        bad = cbad(c)
        fail = cfail(c)
        exit
      end if
    end do
    if (bad /= 0) sh%ovf = 0   ! no half-numbered pool left behind
    if (bad /= 0 .or. sum(cnov) == 0) return
    col(1) = 1
    do c = 2, NCHUNK
      col(c) = col(c - 1) + cnov(c - 1)
    end do
    call pool_reserve(sh, sum(cnov), ierr)
    if (ierr /= 0) then
      sh%ovf = 0
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the CPDI overflow slots; use fewer particles')
      return
    end if
    !$omp parallel do schedule(static) default(shared) private(c, lo, hi, ip, j, nc, sp, f, k9, w9, gx9, gy9, r9)
    do c = 1, NCHUNK
      if (cnov(c) == 0) cycle
      call chunk_range(c, p%n, lo, hi)
      j = col(c)
      do ip = lo, hi
        if (sh%ovf(ip) == 0) cycle
        call shape_cpdi_one(g, p%x(:, ip), p%r(:, ip), k9, w9, gx9, gy9, sh%pidx(:, j), sh%pw(:, j), &
                            sh%pgx(:, j), sh%pgy(:, j), nc, r9, sp, f)
        sh%ovf(ip) = j
        j = j + 1
      end do
    end do
    !$omp end parallel do
  end subroutine shape_compute
end module cpdi_shape
