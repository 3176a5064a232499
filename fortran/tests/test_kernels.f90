!> Fortran-only unit tests of the pure kernels (run by `meson test`, hence `make test`).
program test_kernels
  !! Exits non-zero through the return code of the program's last statement only
  !! (no STOP anywhere in fortran/): failures are counted and reported with `error`.
  use cpdi_kinds, only: wp, ik
  use cpdi_kinematics, only: log_strain, log_strain_lapack
  use cpdi_shape, only: gimp_1d, shape_t, shape_alloc, shape_compute, SHAPE_CPDI, SHAPE_GIMP, SHAPE_MPM
  use cpdi_grid, only: grid_t, grid_init, WALL_SLIP
  use cpdi_particles, only: particles_t, particles_alloc
  use cpdi_status, only: status_t
  use cpdi_step, only: probe_cap
  use cpdi_sim, only: PROBE_MAX
  use cpdi_projection, only: projection_t, projection_alloc, projection_setup, PROJ_CELL
  use cpdi_core_latency, only: core_round_trip
  implicit none
  integer :: nfail, i
  real(wp) :: F(4), e1(3), e2(3), s, ds, tot, h, lp, xp
  integer(ik) :: info
  real(wp) :: u(4)

  nfail = 0
  call random_seed()
  ! log strain: closed form against dsyev for random F with J > 0
  do i = 1, 2000
    call random_number(u)
    F = [0.5_wp + u(1), u(2) - 0.5_wp, u(3) - 0.5_wp, 0.5_wp + u(4)]
    if (F(1)*F(4) - F(2)*F(3) <= 0.05_wp) cycle
    call log_strain(F, e1)
    call log_strain_lapack(F, e2, info)
    if (info /= 0 .or. maxval(abs(e1 - e2)) > 1.0e-12_wp) then
      nfail = nfail + 1
      print '(a,4es12.4,a,es10.2)', 'FAIL log strain F=', F, ' diff=', maxval(abs(e1 - e2))
    end if
  end do
  ! near-isotropic F: series branch
  F = [1.1_wp, 1.0e-9_wp, 0.0_wp, 1.1_wp]
  call log_strain(F, e1)
  if (abs(e1(1) - log(1.1_wp)) > 1.0e-14_wp) then
    nfail = nfail + 1
    print '(a)', 'FAIL log strain of isotropic stretch'
  end if
  ! GIMP partition of unity in 1D
  h = 0.1_wp
  lp = 0.025_wp
  do i = 1, 200
    call random_number(xp)
    xp = 0.3_wp + 0.1_wp*xp
    tot = 0.0_wp
    block
      integer :: k
      real(wp) :: dtot
      dtot = 0.0_wp
      do k = 0, 10
        call gimp_1d(xp - real(k, wp)*h, lp, h, s, ds)
        tot = tot + s
        dtot = dtot + ds
      end do
      if (abs(tot - 1.0_wp) > 1.0e-13_wp .or. abs(dtot) > 1.0e-10_wp) then
        nfail = nfail + 1
        print '(a,es12.4,2es12.4)', 'FAIL gimp partition of unity at ', xp, tot, dtot
      end if
    end block
  end do
  call stencils_within_strip_height(nfail)
  call quadrature_cells_within_strip_height(nfail)
  ! a probe of the slower thread team (one step on it) costs (slow / fast - 1) steps of the
  ! running team; between two probes at the longest gap that is at most about 1 % of the run
  ! for any speed-up up to 64 threads, and the gap is never below PROBE_MAX
  do i = 1, 640
    tot = 1.0_wp + 0.1_wp*real(i, wp)   ! slow / fast
    if ((tot - 1.0_wp)/real(probe_cap(tot, 1.0_wp), wp) > 0.0101_wp .or. probe_cap(tot, 1.0_wp) < PROBE_MAX) then
      nfail = nfail + 1
      print '(a,f8.2,a,i0)', 'FAIL probe cost: slow/fast ', tot, ' gap ', probe_cap(tot, 1.0_wp)
      exit
    end if
  end do
  call round_trip_probe(nfail)
  print '(a,i0,a)', 'fortran kernels: ', nfail, ' failures'
  if (nfail > 0) call exit(1)
contains

  subroutine round_trip_probe(nfail)
    !! The benchmark's cache-line probe: a positive, finite round trip between two threads (a
    !! broken hand-over hangs until the probe's timeout and reports an error), and a refused count.
    integer, intent(inout) :: nfail
    type(status_t) :: st, st0
    real(wp) :: ns
    ! no two cores hand a line back and forth in under 1 ns (4 cycles at 4 GHz); 0.1 s a trip
    ! allows for a partner thread that the kernel deschedules (meson runs test drivers side by side)
    call core_round_trip(500_ik, ns, st)
    if (.not. st%ok() .or. .not. (ns > 1.0_wp .and. ns < 1.0e8_wp)) then
      nfail = nfail + 1
      print '(a,es12.4,1x,a)', 'FAIL core round trip: ns = ', ns, trim(st%msg)
    end if
    call core_round_trip(0_ik, ns, st0)
    if (st0%ok() .or. ns /= 0.0_wp) then
      nfail = nfail + 1
      print '(a)', 'FAIL core round trip: iters = 0 was not refused'
    end if
  end subroutine round_trip_probe

  subroutine stencils_within_strip_height(nfail)
    !! The scatter colouring (cpdi_schedule) is race-free only if every node a particle's
    !! stencil writes, zero weights included, lies in rows row .. row + span of the shape
    !! functions' first row and tallest span: strips are span rows high, and same-colour
    !! strips must touch disjoint rows. Checked for each interpolation on particles whose
    !! domains each lie inside one cell row (CPDI corners in one row: the merged 3 x 3 block
    !! still writes a third row of zeros) and on particles straddling rows.
    integer, intent(inout) :: nfail
    type(grid_t) :: g
    type(particles_t) :: p
    type(shape_t) :: sh
    type(status_t) :: st
    integer(ik) :: kinds(3), kind_i, ip, a, rowk, bad, fail, np, j
    real(wp) :: yoff(2)
    integer :: t, worst
    kinds = [SHAPE_MPM, SHAPE_GIMP, SHAPE_CPDI]
    yoff = [0.5_wp, 1.0_wp]   ! domains centred in a cell row, or on a row boundary
    call grid_init(g, [0.0_wp, 0.0_wp], [8_ik, 12_ik], 1.0_wp, [WALL_SLIP, WALL_SLIP, WALL_SLIP, WALL_SLIP], st)
    np = 16
    call particles_alloc(p, np, st)
    do t = 1, 2
      do ip = 1, np
        j = (ip - 1)/2
        p%x(:, ip) = [2.5_wp + real(mod(ip - 1, 2), wp)*2.0_wp, real(j, wp) + yoff(t)]
        p%r0(:, ip) = [0.2_wp, 0.0_wp, 0.0_wp, 0.2_wp]
        p%r(:, ip) = p%r0(:, ip)
      end do
      do kind_i = 1, 3
        call shape_alloc(sh, kinds(kind_i), np, st)
        call shape_compute(g, p, sh, bad, fail, st)
        if (.not. st%ok() .or. bad /= 0) then
          nfail = nfail + 1
          print '(a,i0)', 'FAIL stencil rows: shape_compute refused the particles, kind ', kinds(kind_i)
          cycle
        end if
        worst = 0
        do ip = 1, np
          do a = 1, size(sh%idx, 1)
            rowk = (sh%idx(a, ip) - 1)/g%nn(1)
            if (rowk < sh%row(ip) .or. rowk > sh%row(ip) + sh%span) worst = worst + 1
          end do
        end do
        if (worst > 0) then
          nfail = nfail + 1
          print '(a,i0,a,i0,a,i0)', 'FAIL stencil rows: kind ', kinds(kind_i), ': ', worst, &
            ' slots write a node row beyond row + span, span = ', sh%span
        end if
      end do
    end do
  end subroutine stencils_within_strip_height

  subroutine quadrature_cells_within_strip_height(nfail)
    !! The cell projection's scatter (its own strips, built by projection_setup) is race-free
    !! only if every cell a particle's quadrature points fall in lies in cell rows
    !! row .. row + width of its first row and the strips' height: same-colour strips must
    !! touch disjoint rows. Checked on CPDI domains whose quadrature points span three cell
    !! rows, two and one.
    integer, intent(inout) :: nfail
    type(grid_t) :: g
    type(particles_t) :: p
    type(projection_t) :: pr
    type(status_t) :: st
    logical, allocatable :: mask(:)
    integer(ik) :: ip, q, np, rowq, worst
    real(wp) :: ry(3)
    integer :: t
    ry = [1.2_wp, 0.6_wp, 0.2_wp]   ! half heights: quadrature points +-0.69, +-0.35, +-0.12 cells
    call grid_init(g, [0.0_wp, 0.0_wp], [8_ik, 12_ik], 1.0_wp, [WALL_SLIP, WALL_SLIP, WALL_SLIP, WALL_SLIP], st)
    np = 16
    call particles_alloc(p, np, st)
    allocate (mask(np), source=.true.)
    do t = 1, 3
      do ip = 1, np
        p%x(:, ip) = [2.5_wp + real(mod(ip - 1, 2), wp)*2.0_wp, 2.5_wp + real((ip - 1)/2, wp)]
        p%r0(:, ip) = [0.3_wp, 0.0_wp, 0.0_wp, ry(t)]
        p%r(:, ip) = p%r0(:, ip)
      end do
      call projection_alloc(pr, g, np, st)
      call projection_setup(pr, PROJ_CELL, SHAPE_CPDI, g, p, mask, st)
      if (.not. st%ok()) then
        nfail = nfail + 1
        print '(a)', 'FAIL quadrature cell rows: projection_setup refused the particles'
        return
      end if
      worst = 0
      do ip = 1, np
        do q = 1, pr%nq
          rowq = (pr%qc(q, ip) - 1)/(g%nn(1) - 1)
          if (rowq < pr%row(ip) .or. rowq > pr%row(ip) + pr%sp%width) worst = worst + 1
        end do
      end do
      if (worst > 0) then
        nfail = nfail + 1
        print '(a,f5.2,a,i0,a,i0)', 'FAIL quadrature cell rows: half height ', ry(t), ': ', worst, &
          ' quadrature points write a cell row beyond row + strip height ', pr%sp%width
      end if
    end do
  end subroutine quadrature_cells_within_strip_height
end program test_kernels
