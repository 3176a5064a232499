!> Fortran-only unit tests of the pure kernels (run by `meson test`, hence `make test`).
program test_kernels
  !! Exits non-zero through the return code of the program's last statement only
  !! (no STOP anywhere in fortran/): failures are counted and reported with `error`.
  use cpdi_kinds, only: wp, ik
  use cpdi_kinematics, only: log_strain, log_strain_lapack
  use cpdi_shape, only: gimp_1d
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
  print '(a,i0,a)', 'fortran kernels: ', nfail, ' failures'
  if (nfail > 0) call exit(1)
end program test_kernels
