!> Finite-deformation kinematics: b = F F^T and the logarithmic strain 1/2 log b.
module cpdi_kinematics
  !! Plane strain: F33 = 1, so b33 = 1 and the out-of-plane log strain is zero. The
  !! in-plane 2x2 log is computed in closed form from b's eigen-decomposition written
  !! as a spectral function, `1/2 [ (f1+f2)/2 I + (f1-f2)/(l1-l2) (b - (l1+l2)/2 I) ]`
  !! with `f = log`, and a series for the divided difference when the eigenvalues are
  !! close, so it stays accurate to round-off for any F with J > 0. `log_strain_lapack`
  !! does the same with LAPACK `dsyev`; the tests hold the two together.
  use cpdi_kinds, only: wp, ik
  implicit none
  private

  public :: left_cauchy_green, log_strain, log_strain_lapack, det2, map_domains

  interface
    subroutine dsyev(jobz, uplo, n, a, lda, w, work, lwork, info)
      import :: wp
      character(len=1), intent(in) :: jobz, uplo
      integer, intent(in) :: n, lda, lwork
      real(wp), intent(inout) :: a(lda, *)
      real(wp), intent(out) :: w(*), work(*)
      integer, intent(out) :: info
    end subroutine dsyev
  end interface

contains

  pure real(wp) function det2(F)
    !! Determinant of a 2x2 tensor stored [A11, A21, A12, A22].
    real(wp), intent(in) :: F(4)
    det2 = F(1)*F(4) - F(3)*F(2)
  end function det2

  pure subroutine map_domains(lo, hi, F, r0, r)
    !! CPDI domain vectors carried by F, r_k = F r0_k (layout [r1x, r1y, r2x, r2y]), for
    !! particles lo..hi on plain arrays.
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(in) :: F(4, *), r0(4, *)
    real(wp), intent(inout) :: r(4, *)
    integer(ik) :: ip
    do ip = lo, hi
      r(1, ip) = F(1, ip)*r0(1, ip) + F(3, ip)*r0(2, ip)
      r(2, ip) = F(2, ip)*r0(1, ip) + F(4, ip)*r0(2, ip)
      r(3, ip) = F(1, ip)*r0(3, ip) + F(3, ip)*r0(4, ip)
      r(4, ip) = F(2, ip)*r0(3, ip) + F(4, ip)*r0(4, ip)
    end do
  end subroutine map_domains

  pure subroutine left_cauchy_green(F, b)
    !! b = F F^T as [b11, b22, b12].
    real(wp), intent(in) :: F(4)
    real(wp), intent(out) :: b(3)
    b(1) = F(1)*F(1) + F(3)*F(3)
    b(2) = F(2)*F(2) + F(4)*F(4)
    b(3) = F(1)*F(2) + F(3)*F(4)
  end subroutine left_cauchy_green

  pure subroutine log_strain(F, eps)
    !! eps = 1/2 log(F F^T), in-plane components [e11, e22, e12]. Requires det F > 0.
    real(wp), intent(in) :: F(4)
    real(wp), intent(out) :: eps(3)
    real(wp) :: b(3), m, d, l1, l2, s, dd, avg
    call left_cauchy_green(F, b)
    m = 0.5_wp*(b(1) + b(2))
    d = sqrt((0.5_wp*(b(1) - b(2)))**2 + b(3)**2)
    l1 = m + d
    ! l1*l2 = det(b) = J^2: avoids cancellation in m - d when one stretch is tiny.
    l2 = det2(F)**2/l1
    ! avg = (log l1 + log l2)/2 = log J; dd = (log l1 - log l2)/(l1 - l2) with l1 - l2 = 2d.
    avg = log(det2(F))
    s = d/m
    if (s < 1.0e-3_wp) then
      ! atanh(s)/s series: dd = (1/m)(1 + s^2/3 + s^4/5 + s^6/7), error O(s^8)
      dd = (1.0_wp + s*s*(1.0_wp/3.0_wp + s*s*(1.0_wp/5.0_wp + s*s/7.0_wp)))/m
    else
      dd = log(l1/l2)/(2.0_wp*d)
    end if
    eps(1) = 0.5_wp*(avg + dd*(b(1) - m))
    eps(2) = 0.5_wp*(avg + dd*(b(2) - m))
    eps(3) = 0.5_wp*dd*b(3)
  end subroutine log_strain

  subroutine log_strain_lapack(F, eps, info)
    !! Reference implementation of `log_strain` through LAPACK dsyev.
    real(wp), intent(in) :: F(4)
    real(wp), intent(out) :: eps(3)
    integer(ik), intent(out) :: info
    real(wp) :: b(3), a(2, 2), w(2), work(16), e(2, 2)
    integer :: inf, k
    call left_cauchy_green(F, b)
    a = reshape([b(1), b(3), b(3), b(2)], [2, 2])
    call dsyev('V', 'U', 2, a, 2, w, work, 16, inf)
    info = inf
    eps = 0.0_wp
    if (inf /= 0 .or. any(w <= 0.0_wp)) then
      if (inf == 0) info = -1
      return
    end if
    e = 0.0_wp
    do k = 1, 2
      e = e + 0.5_wp*log(w(k))*spread(a(:, k), 2, 2)*spread(a(:, k), 1, 2)
    end do
    eps = [e(1, 1), e(2, 2), e(1, 2)]
  end subroutine log_strain_lapack
end module cpdi_kinematics
