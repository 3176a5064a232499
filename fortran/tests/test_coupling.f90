!> Fortran-only consistency tests of the batty coupling's operator (cpdi_coupling), run by
!> `meson test`: a rectangular solid in a tank of water on a 16 x 16 MAC grid, face solid
!> volumes from the exact overlap of the faces' control volumes with the rectangle.
program test_coupling
  !! 1. Archimedes: a hydrostatic pressure gives the solid faces' impulses summing to
  !!    rho g sum_f V_s,f = rho g V (exact), no horizontal force; a uniform pressure gives none.
  !! 2. The velocity update is the transpose of the constraint: for random p, (rho / dt) C(du(p))
  !!    equals the assembled A p (water faces from mac_project, solid faces I_f / m_f).
  !! 3. The projection: after solving, C(u) vanishes to the solver's tolerance and the kinetic
  !!    energy of the face masses (water rho h^2 (1 - w_f), solid m_f) does not grow.
  !! Cases: the solid submerged away from the walls; the solid on the floor against the left wall.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t
  use cpdi_pressure, only: mac_t, mac_alloc, mac_mark_outside, mac_walls, mac_solve, mac_project, mac_apply, &
                           CELL_FLUID, CELL_AIR, CELL_SOLID
  use cpdi_coupling, only: cpl_fractions, cpl_classify, cpl_constraint, cpl_assemble, cpl_impulse
  implicit none
  integer, parameter :: NC = 16
  real(wp), parameter :: H = 0.1_wp, RHO = 1000.0_wp, RHOS = 800.0_wp, G = 9.81_wp, YS = 1.2_wp, DT = 1.0e-3_wp
  real(wp), parameter :: MTOL = 1.0e-12_wp
  integer :: nfail

  nfail = 0
  call random_seed()
  call run_case('submerged', [0.53_wp, 0.31_wp], [1.07_wp, 0.77_wp], .true.)
  call run_case('on the floor, at the wall', [0.0_wp, 0.0_wp], [0.46_wp, 0.38_wp], .false.)
  call run_case('piercing the surface', [0.62_wp, 1.03_wp], [1.18_wp, 1.41_wp], .false.)
  print '(a,i0,a)', 'coupling operator: ', nfail, ' failures'
  if (nfail > 0) call exit(1)

contains

  pure real(wp) function overlap(a0, a1, b0, b1)
    real(wp), intent(in) :: a0, a1, b0, b1
    overlap = max(0.0_wp, min(a1, b1) - max(a0, b0))
  end function overlap

  subroutine check(ok, what, val)
    logical, intent(in) :: ok
    character(len=*), intent(in) :: what
    real(wp), intent(in) :: val
    if (.not. ok) then
      nfail = nfail + 1
      print '(a,a,es12.4)', 'FAIL ', what, val
    end if
  end subroutine check

  subroutine run_case(name, bmin, bmax, archimedes)
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: bmin(2), bmax(2)
    logical, intent(in) :: archimedes
    type(mac_t) :: mc
    type(status_t) :: st
    integer(ik) :: nn(2), lo(2), hi(2), n, n1, i, j, k, lo1, lo2
    real(wp), allocatable :: uvs(:), vvs(:), usm(:), vsm(:), us(:), vs(:), wu(:), wv(:), phi(:), fillw(:), &
                             iu(:), iv(:), cf(:), ap(:), r(:), u0(:), v0(:), us0(:), vs0(:), du(:), dv(:), zero(:), &
                             sfill(:)
    real(wp) :: x0, y0, xc, yc, vol, fy, fx, err, erra, scale, ke0, ke1, cmax, c0
    logical :: allwet
    character(len=80) :: tag
    tag = ' ['//name//']'
    nn = NC + 5
    lo = 3
    hi = NC + 2
    n = nn(1)*nn(2)
    n1 = nn(1)
    lo1 = lo(1)
    lo2 = lo(2)
    call mac_alloc(mc, nn, lo, hi, H, st)
    call mac_mark_outside(mc, [.true., .true., .true., .false.])
    allocate (uvs(n), vvs(n), usm(n), vsm(n), us(n), vs(n), wu(n), wv(n), phi(n), fillw(n), iu(n), iv(n), cf(n), &
              ap(n), r(n), u0(n), v0(n), us0(n), vs0(n), du(n), dv(n), zero(n), sfill(n))
    zero = 0.0_wp
    uvs = 0.0_wp
    vvs = 0.0_wp
    fillw = 0.0_wp
    ! faces: u face (i, j) at x = (i - lo) h, control volume [x - h/2, x + h/2] x [(j - lo) h, (j - lo + 1) h];
    ! v face (i, j) at y = (j - lo) h, control volume [(i - lo) h, (i - lo + 1) h] x [y - h/2, y + h/2]
    do j = 2, nn(2) - 1
      do i = 2, n1 - 1
        k = i + (j - 1)*n1
        x0 = real(i - lo1, wp)*H
        y0 = real(j - lo2, wp)*H
        uvs(k) = overlap(x0 - 0.5_wp*H, x0 + 0.5_wp*H, bmin(1), bmax(1))*overlap(y0, y0 + H, bmin(2), bmax(2))
        vvs(k) = overlap(x0, x0 + H, bmin(1), bmax(1))*overlap(y0 - 0.5_wp*H, y0 + 0.5_wp*H, bmin(2), bmax(2))
        if (i >= lo1 .and. i <= hi(1) .and. j >= lo2 .and. j <= hi(2)) then
          fillw(k) = (overlap(y0, y0 + H, 0.0_wp, YS)*H &
                      - overlap(x0, x0 + H, bmin(1), bmax(1))*overlap(y0, y0 + H, bmin(2), min(bmax(2), YS)))/H**2
          mc%fill(k) = fillw(k) + overlap(x0, x0 + H, bmin(1), bmax(1))*overlap(y0, y0 + H, bmin(2), bmax(2))/H**2
          xc = x0 + 0.5_wp*H
          yc = y0 + 0.5_wp*H
          if (yc < YS .and. .not. (xc > bmin(1) .and. xc < bmax(1) .and. yc > bmin(2) .and. yc < bmax(2))) &
            mc%cell(k) = CELL_FLUID
        end if
      end do
    end do
    vol = product(bmax - bmin)
    call random_number(usm)
    usm = RHOS*uvs*(0.7_wp + 0.6_wp*usm)
    call random_number(vsm)
    vsm = RHOS*vvs*(0.7_wp + 0.6_wp*vsm)
    call cpl_fractions(mc, uvs, vvs, wu, wv, phi)
    call cpl_classify(mc, fillw, phi, wu, wv, sfill)

    ! 1. Archimedes and no force from a uniform pressure
    if (archimedes) then
      allwet = .true.
      do j = lo2, hi(2)
        do i = lo1, hi(1)
          k = i + (j - 1)*n1
          if ((abs(wu(k + 1) - wu(k)) > 1.0e-12_wp .or. abs(wv(k + n1) - wv(k)) > 1.0e-12_wp) .and. &
              mc%cell(k) /= CELL_FLUID) then
            allwet = .false.
            print '(a,2i4,5f8.4)', 'dry boundary cell', i, j, phi(k), fillw(k), mc%fill(k), wu(k + 1) - wu(k), &
              wv(k + n1) - wv(k)
          end if
        end do
      end do
      call check(allwet, 'every cell on the solid boundary is water'//trim(tag), 0.0_wp)
      mc%p = 0.0_wp
      do j = lo2, hi(2)
        do i = lo1, hi(1)
          k = i + (j - 1)*n1
          if (mc%cell(k) == CELL_FLUID) mc%p(k) = RHO*G*(YS - (real(j - lo2, wp) + 0.5_wp)*H)
        end do
      end do
      call cpl_impulse(mc, DT, wu, wv, usm, vsm, MTOL, iu, iv)
      fy = sum(iv)/DT
      fx = sum(iu)/DT
      call check(abs(fy - RHO*G*vol) <= 1.0e-12_wp*RHO*G*vol, 'hydrostatic: F_y - rho g V'//trim(tag), &
                 fy/(RHO*G*vol) - 1.0_wp)
      call check(abs(fy - RHO*G*sum(wv)*H**2) <= 1.0e-12_wp*RHO*G*vol, 'hydrostatic: F_y - rho g sum w h^2'//trim(tag), &
                 fy - RHO*G*sum(wv)*H**2)
      call check(abs(fx) <= 1.0e-12_wp*RHO*G*vol, 'hydrostatic: F_x'//trim(tag), fx)
      print '(a,a,a,es10.3,a,es10.3)', 'coupling', trim(tag), ': hydrostatic F_y / (rho g V) - 1 ', &
        fy/(RHO*G*vol) - 1.0_wp, ', F_x / (rho g V) ', fx/(RHO*G*vol)
      where (mc%cell == CELL_FLUID) mc%p = 1234.5_wp
      call cpl_impulse(mc, DT, wu, wv, usm, vsm, MTOL, iu, iv)
      call check(abs(sum(iu)) + abs(sum(iv)) <= 1.0e-12_wp*1234.5_wp*H*DT*NC, 'uniform p: net impulse'//trim(tag), &
                 abs(sum(iu)) + abs(sum(iv)))
    end if

    ! 2. A p = (rho / dt) C(du(p)) for a random p
    mc%u = 0.0_wp
    mc%v = 0.0_wp
    us = 0.0_wp
    vs = 0.0_wp
    call mac_walls(mc)
    call cpl_assemble(mc, DT, RHO, wu, wv, usm, vsm, us, vs, MTOL, .true., 0.0_wp)
    call random_number(r)
    mc%p = 0.0_wp
    where (mc%cell == CELL_FLUID) mc%p = 1000.0_wp*(r - 0.5_wp)
    ap = 0.0_wp
    call mac_apply(mc, mc%p, ap)
    call mac_project(mc, DT, RHO)
    call cpl_impulse(mc, DT, wu, wv, usm, vsm, MTOL, iu, iv)
    where (usm > MTOL) us = iu/usm
    where (vsm > MTOL) vs = iv/vsm
    call cpl_constraint(mc, mc%u, mc%v, wu, wv, usm, vsm, us, vs, MTOL, .true., cf)
    err = maxval(abs(RHO/DT*cf - ap))
    scale = maxval(abs(ap))
    erra = err/scale
    call check(err <= 1.0e-11_wp*scale, 'A p against (rho/dt) C(M^-1 C^T p)'//trim(tag), err/scale)
    call check(count(mc%cell == CELL_FLUID) > 20, 'water cells'//trim(tag), real(count(mc%cell == CELL_FLUID), wp))
    ! the system is symmetric: sum_c q_c (A p)_c = sum_c p_c (A q)_c
    block
      real(wp) :: q(n), aq(n)
      call random_number(q)
      where (mc%cell /= CELL_FLUID) q = 0.0_wp
      aq = 0.0_wp
      call mac_apply(mc, q, aq)
      err = abs(sum(q*ap) - sum(mc%p*aq))
      call check(err <= 1.0e-12_wp*sum(abs(q*ap)), 'A symmetric'//trim(tag), err)
    end block

    ! 3. the projection of random velocities
    call random_number(u0)
    call random_number(v0)
    call random_number(us0)
    call random_number(vs0)
    u0 = u0 - 0.5_wp
    v0 = v0 - 0.5_wp
    us0 = merge(us0 - 0.5_wp, 0.0_wp, usm > MTOL)
    vs0 = merge(vs0 - 0.5_wp, 0.0_wp, vsm > MTOL)
    ! faces at a wall: the solid's velocity is the wall's (its nodes are held)
    do j = 2, nn(2)
      do i = 2, n1
        k = i + (j - 1)*n1
        if (mc%cell(k - 1) == CELL_SOLID .or. mc%cell(k) == CELL_SOLID) us0(k) = 0.0_wp
        if (mc%cell(k - n1) == CELL_SOLID .or. mc%cell(k) == CELL_SOLID) vs0(k) = 0.0_wp
      end do
    end do
    mc%u = u0
    mc%v = v0
    call mac_walls(mc)
    u0 = mc%u
    v0 = mc%v
    call cpl_constraint(mc, u0, v0, wu, wv, usm, vsm, us0, vs0, MTOL, .true., cf)
    c0 = maxval(abs(cf))
    call cpl_assemble(mc, DT, RHO, wu, wv, usm, vsm, us0, vs0, MTOL, .true., 0.0_wp)
    block
      logical :: conv
      call mac_solve(mc, 1.0e-12_wp, 2000_ik, conv)
      call check(conv, 'solve converged'//trim(tag), mc%resid)
    end block
    call mac_project(mc, DT, RHO)
    call cpl_impulse(mc, DT, wu, wv, usm, vsm, MTOL, iu, iv)
    us = us0
    vs = vs0
    where (usm > MTOL) us = us0 + iu/usm
    where (vsm > MTOL) vs = vs0 + iv/vsm
    call cpl_constraint(mc, mc%u, mc%v, wu, wv, usm, vsm, us, vs, MTOL, .true., cf)
    cmax = maxval(abs(cf))
    call check(cmax <= 1.0e-9_wp*c0, 'C(u) after the projection'//trim(tag), cmax/c0)
    du = (1.0_wp - wu)*RHO*H**2
    dv = (1.0_wp - wv)*RHO*H**2
    ke0 = 0.5_wp*(sum(du*u0**2) + sum(dv*v0**2) + sum(usm*us0**2) + sum(vsm*vs0**2))
    ke1 = 0.5_wp*(sum(du*mc%u**2) + sum(dv*mc%v**2) + sum(usm*us**2) + sum(vsm*vs**2))
    call check(ke1 <= ke0*(1.0_wp + 1.0e-12_wp) .and. ke1 < ke0, 'kinetic energy grows'//trim(tag), ke1/ke0 - 1.0_wp)
    print '(a,a,a,es10.3,a,es10.3,a,i0,a,es10.3)', 'coupling', trim(tag), ': A vs C^T rel ', erra, &
      '; C after/before ', cmax/c0, '; CG iterations ', mc%iters, '; KE after/before - 1 ', ke1/ke0 - 1.0_wp
  end subroutine run_case
end program test_coupling
