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
  use cpdi_memory, only: advise_huge, advise_huge_int
  use cpdi_grid, only: grid_t
  use cpdi_particles, only: particles_t
  use cpdi_schedule, only: NCHUNK, chunk_range, blocks_t, block_start, block_next
  implicit none
  private

  integer(ik), parameter, public :: SHAPE_MPM = 0
  integer(ik), parameter, public :: SHAPE_GIMP = 1
  integer(ik), parameter, public :: SHAPE_CPDI = 2

  integer(ik), parameter :: CPDI_BATCH = 16   !! particles per vectorised CPDI batch

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
    integer(ik) :: cb(5, NCHUNK) = 0       !! per block (shape_compute): first failing particle, its cause,
                                           !! pool columns needed, first pool column, tallest span
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
      call advise_huge_int(sh%idx, size(sh%idx))   ! before the first touch (cpdi_memory)
      call advise_huge(sh%w, size(sh%w))
      call advise_huge(sh%gx, size(sh%gx))
      call advise_huge(sh%gy, size(sh%gy))
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

  pure subroutine shape_cpdi_batch(nb, x, r, gorig, rh, nn, k, w, gx, gy, row, span, merged)
    !! CPDI1 weights of nb <= CPDI_BATCH particles in the usual case: all four corners of
    !! the domain r = [r1x, r1y, r2x, r2y] lie in one 2x2-cell block of the grid, and the 16
    !! corner-node pairs merge into the 3x3 node stencil. Corner c's bilinear values there
    !! are the outer product P_c = X_c (x) Y_c of the 1D hats X(l) = max(0, 1 - |u - l|),
    !! l = 0, 1, 2, u = its local coordinate in [0, 2), and likewise Y:
    !! w = (P1 + P2 + P3 + P4)/4 and, as g3 = -g1 and g4 = -g2, grad = g1 (P1 - P3) +
    !! g2 (P2 - P4). Every loop runs across the batch's particles (lanes), so the compiler
    !! vectorises them. A particle for which this does not hold (merged = .false.:
    !! inverted, outside the grid, or a domain spanning more cells) is left untouched, for
    !! shape_cpdi_one. row, span: first node row of the stencil, height minus one.
    integer(ik), intent(in) :: nb, nn(2)
    real(wp), intent(in) :: x(2, nb), r(4, nb), gorig(2), rh
    integer(ik), intent(inout) :: k(9, nb), row(nb), span(nb)
    real(wp), intent(inout) :: w(9, nb), gx(9, nb), gy(9, nb)
    logical, intent(out) :: merged(nb)
    real(wp), parameter :: SG(2, 4) = reshape([-1.0_wp, -1.0_wp, 1.0_wp, -1.0_wp, 1.0_wp, 1.0_wp, -1.0_wp, 1.0_wp], &
                                              [2, 4])   ! corner c = x + SG(1, c) r1 + SG(2, c) r2
    real(wp) :: su(CPDI_BATCH, 4), sv(CPDI_BATCH, 4), hx(CPDI_BATCH, 3, 4), hy(CPDI_BATCH, 3, 4)
    real(wp) :: ga(CPDI_BATCH, 2), gb(CPDI_BATCH, 2), bw(CPDI_BATCH, 9), bx(CPDI_BATCH, 9), by(CPDI_BATCH, 9)
    real(wp) :: cross, rv, umin, umax, vmin, vmax, u, v, p1, p2, p3, p4
    integer(ik) :: l, c, li, lj, a, bi(CPDI_BATCH), bj(CPDI_BATCH), ei, ej
    integer(ik) :: nout(CPDI_BATCH)
    !$omp simd private(cross, rv)
    do l = 1, nb
      cross = r(1, l)*r(4, l) - r(2, l)*r(3, l)
      merged(l) = cross > 0.0_wp
      rv = 1.0_wp/(4.0_wp*max(cross, tiny(cross)))   ! 1 / V_p (finite in an inverted lane)
      ga(l, 1) = (r(2, l) - r(4, l))*rv   ! multiplies N(x1) - N(x3)
      ga(l, 2) = (r(3, l) - r(1, l))*rv
      gb(l, 1) = (r(2, l) + r(4, l))*rv   ! multiplies N(x2) - N(x4)
      gb(l, 2) = (-r(1, l) - r(3, l))*rv
    end do
    do c = 1, 4
      !$omp simd
      do l = 1, nb
        su(l, c) = (x(1, l) + SG(1, c)*r(1, l) + SG(2, c)*r(3, l) - gorig(1))*rh
        sv(l, c) = (x(2, l) + SG(1, c)*r(2, l) + SG(2, c)*r(4, l) - gorig(2))*rh
      end do
    end do
    ! corner cells with no integer division; the truncation is monotonic, so the extreme
    ! cells come from the extreme corners (clamped: a failing lane converts no junk)
    !$omp simd private(umin, umax, vmin, vmax, ei, ej)
    do l = 1, nb
      umin = lesser(lesser(su(l, 1), su(l, 2)), lesser(su(l, 3), su(l, 4)))
      umax = greater(greater(su(l, 1), su(l, 2)), greater(su(l, 3), su(l, 4)))
      vmin = lesser(lesser(sv(l, 1), sv(l, 2)), lesser(sv(l, 3), sv(l, 4)))
      vmax = greater(greater(sv(l, 1), sv(l, 2)), greater(sv(l, 3), sv(l, 4)))
      bi(l) = int(lesser(greater(umin, 0.0_wp), real(nn(1), wp)), ik)
      bj(l) = int(lesser(greater(vmin, 0.0_wp), real(nn(2), wp)), ik)
      ei = int(lesser(greater(umax, 0.0_wp), real(nn(1), wp)), ik)
      ej = int(lesser(greater(vmax, 0.0_wp), real(nn(2), wp)), ik)
      span(l) = ej + 1 - bj(l)
      ! all corners inside the grid (x < n - 1 <=> n - 1 - x > 0 exactly), in a 2x2-cell block
      ! (counted, not chained with .and., which leaves a branch in the loop)
      nout(l) = merge(0, 1, lesser(umin, vmin) >= 0.0_wp) + &
                merge(0, 1, lesser(real(nn(1) - 1, wp) - umax, real(nn(2) - 1, wp) - vmax) > 0.0_wp) + &
                merge(0, 1, max(ei - bi(l), span(l) - 1) <= 1)
    end do
    do c = 1, 4
      !$omp simd private(u, v)
      do l = 1, nb
        u = su(l, c) - real(bi(l), wp)
        v = sv(l, c) - real(bj(l), wp)
        hx(l, 1, c) = max(0.0_wp, 1.0_wp - u)
        hx(l, 2, c) = max(0.0_wp, 1.0_wp - abs(u - 1.0_wp))
        hx(l, 3, c) = max(0.0_wp, u - 1.0_wp)
        hy(l, 1, c) = max(0.0_wp, 1.0_wp - v)
        hy(l, 2, c) = max(0.0_wp, 1.0_wp - abs(v - 1.0_wp))
        hy(l, 3, c) = max(0.0_wp, v - 1.0_wp)
      end do
    end do
    do lj = 1, 3
      do li = 1, 3
        a = li + 3*lj - 3
        !$omp simd private(p1, p2, p3, p4)
        do l = 1, nb
          p1 = hx(l, li, 1)*hy(l, lj, 1)
          p2 = hx(l, li, 2)*hy(l, lj, 2)
          p3 = hx(l, li, 3)*hy(l, lj, 3)
          p4 = hx(l, li, 4)*hy(l, lj, 4)
          bw(l, a) = 0.25_wp*((p1 + p2) + (p3 + p4))
          bx(l, a) = ga(l, 1)*(p1 - p3) + gb(l, 1)*(p2 - p4)
          by(l, a) = ga(l, 2)*(p1 - p3) + gb(l, 2)*(p2 - p4)
        end do
      end do
    end do
    do l = 1, nb
      merged(l) = merged(l) .and. nout(l) == 0
      if (.not. merged(l)) cycle
      row(l) = bj(l)
      span(l) = 2   ! the 3 x 3 block's rows bj..bj + 2 are all written (zero weights in the third
                    ! when every corner lies in one cell row): the strips must be that tall
      k(:, l) = bi(l) + 1 + bj(l)*nn(1) + [0, 1, 2, nn(1), nn(1) + 1, nn(1) + 2, 2*nn(1), 2*nn(1) + 1, 2*nn(1) + 2]
      w(:, l) = bw(l, :)
      gx(:, l) = bx(l, :)
      gy(:, l) = by(l, :)
    end do
  contains
    elemental real(wp) function lesser(a, b)
      !! min(a, b) as a plain selection (gfortran's MIN keeps a branch for NaN arguments,
      !! which stops the vectoriser; a NaN corner fails the range test anyway)
      real(wp), intent(in) :: a, b
      lesser = merge(a, b, a < b)
    end function lesser

    elemental real(wp) function greater(a, b)
      !! max(a, b) as a plain selection (see lesser)
      real(wp), intent(in) :: a, b
      greater = merge(a, b, a > b)
    end function greater
  end subroutine shape_cpdi_batch

  pure subroutine shape_cpdi_one(g, x, r, k, w, gx, gy, ko, wo, gxo, gyo, c0, span, fail)
    !! CPDI1 weights at one particle with domain vectors r = [r1x, r1y, r2x, r2y], in the
    !! general form: the 4 x 4 corner-node pairs, slots 1..9 in k, w, gx, gy and slots
    !! 10..16 in ko, wo, gxo, gyo (a node may appear twice: consumers add them, exactly).
    !! For the particles shape_cpdi_batch does not merge. c0 and span are the first node row
    !! of the stencil and its height minus one.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2), r(4)
    integer(ik), intent(out) :: k(9), ko(7)
    real(wp), intent(out) :: w(9), gx(9), gy(9), wo(7), gxo(7), gyo(7)
    integer(ik), intent(out) :: c0, span, fail
    real(wp) :: cross, rv, xc(2, 4), gc(2, 4), nv(4), ga(2), gb(2), rh, su, sv, u, v
    real(wp) :: w16(16), gx16(16), gy16(16)
    integer(ik) :: c, s0, i0(4), j0(4), base, nn1, k16(16)
    fail = SHAPE_FAIL_NONE
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
    do c = 1, 4
      su = (xc(1, c) - g%gorig(1))*rh
      sv = (xc(2, c) - g%gorig(2))*rh
      if (.not. (su >= 0.0_wp .and. sv >= 0.0_wp .and. su < real(nn1 - 1, wp) &
                 .and. sv < real(g%nn(2) - 1, wp))) then
        fail = SHAPE_FAIL_OUTSIDE
        call clear(k, w, gx, gy)
        call clear(ko, wo, gxo, gyo)
        return
      end if
      i0(c) = int(su, ik)
      j0(c) = int(sv, ik)
      u = su - real(i0(c), wp)
      v = sv - real(j0(c), wp)
      nv = [(1.0_wp - u)*(1.0_wp - v), u*(1.0_wp - v), (1.0_wp - u)*v, u*v]
      s0 = 4*(c - 1)
      base = i0(c) + 1 + j0(c)*nn1
      k16(s0 + 1:s0 + 4) = [base, base + 1, base + nn1, base + nn1 + 1]
      w16(s0 + 1:s0 + 4) = 0.25_wp*nv
      gx16(s0 + 1:s0 + 4) = nv*gc(1, c)
      gy16(s0 + 1:s0 + 4) = nv*gc(2, c)
    end do
    c0 = minval(j0)
    span = maxval(j0) + 1 - c0
    k = k16(1:9)
    w = w16(1:9)
    gx = gx16(1:9)
    gy = gy16(1:9)
    ko = k16(10:16)
    wo = w16(10:16)
    gxo = gx16(10:16)
    gyo = gy16(10:16)
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
    !! Weights of every particle (OpenMP over fixed particle blocks; orphaned worksharing, so
    !! every thread of a parallel region calls it, and bad, fail must be shared). On failure, `bad` is
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
    integer(ik) :: ip, f, c, lo, hi, span, sp, j
    type(blocks_t) :: blk
    integer(ik) :: ko(7), k9(9), r9, b0, b1, bspan(CPDI_BATCH)
    real(wp) :: lp(2), wo(7), gxo(7), gyo(7), w9(9), gx9(9), gy9(9)
    logical :: merged(CPDI_BATCH), second
    integer :: ierr
    ! Orphaned worksharing (the step's parallel region, or serial outside one): the per-block
    ! results live in sh%cb (shared) and are combined in a single, in block order.
    associate (cbad => sh%cb(1, :), cfail => sh%cb(2, :), cnov => sh%cb(3, :), col => sh%cb(4, :), &
               cspan => sh%cb(5, :))
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, p%n, lo, hi)
      span = 1
      cbad(c) = 0
      cfail(c) = SHAPE_FAIL_NONE
      cnov(c) = 0
      if (sh%kind == SHAPE_CPDI) then
        do b0 = lo, hi, CPDI_BATCH
          b1 = min(b0 + CPDI_BATCH - 1, hi)
          call shape_cpdi_batch(b1 - b0 + 1, p%x(:, b0:b1), p%r(:, b0:b1), g%gorig, 1.0_wp/g%h, g%nn, &
                                sh%idx(:, b0:b1), sh%w(:, b0:b1), sh%gx(:, b0:b1), sh%gy(:, b0:b1), sh%row(b0:b1), &
                                bspan, merged)
          do ip = b0, b1
            sh%ovf(ip) = 0
            if (merged(ip - b0 + 1)) then
              span = max(span, bspan(ip - b0 + 1))
              cycle
            end if
            call shape_cpdi_one(g, p%x(:, ip), p%r(:, ip), sh%idx(:, ip), sh%w(:, ip), sh%gx(:, ip), &
                                sh%gy(:, ip), ko, wo, gxo, gyo, sh%row(ip), sp, f)
            if (f == SHAPE_FAIL_NONE) then   ! a pool column, numbered below
              sh%ovf(ip) = -1
              cnov(c) = cnov(c) + 1
              span = max(span, sp)
            else if (cbad(c) == 0) then
              cbad(c) = ip
              cfail(c) = f
            end if
          end do
        end do
        cspan(c) = span
        cycle
      end if
      do ip = lo, hi
        select case (sh%kind)
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
      cspan(c) = span
    end do
    !$omp barrier
    !$omp single
    sh%span = maxval(cspan)
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
    if (bad == 0 .and. sum(cnov) > 0) then
      col(1) = 1
      do c = 2, NCHUNK
        col(c) = col(c - 1) + cnov(c - 1)
      end do
      call pool_reserve(sh, sum(cnov), ierr)
      if (ierr /= 0) then
        sh%ovf = 0
        call st%set(CPDI_ERR_ALLOC, 'could not allocate the CPDI overflow slots; use fewer particles')
      end if
    end if
    second = bad == 0 .and. sum(cnov) > 0 .and. st%ok()
    !$omp end single copyprivate(second)
    ! (the decision is broadcast: bad and st were set by the single's thread)
    if (second) then
      call block_start(blk)
      do while (block_next(blk, c))
        if (cnov(c) == 0) cycle
        call chunk_range(c, p%n, lo, hi)
        j = col(c)
        do ip = lo, hi
          if (sh%ovf(ip) == 0) cycle
          call shape_cpdi_one(g, p%x(:, ip), p%r(:, ip), k9, w9, gx9, gy9, sh%pidx(:, j), sh%pw(:, j), &
                              sh%pgx(:, j), sh%pgy(:, j), r9, sp, f)
          sh%ovf(ip) = j
          j = j + 1
        end do
      end do
      !$omp barrier
    end if
    end associate
  end subroutine shape_compute
end module cpdi_shape
