!> Multi-field volumetric anti-locking projection (Mast et al. 2012; Hamad et al. 2016).
module cpdi_projection
  !! A scalar particle field theta_p (volumetric strain increment, mean stress) is replaced
  !! by its mass-weighted L2 projection onto a lower-order field S(x) alpha:
  !!
  !!   H alpha = int S^T theta dm,   H = int S^T S dm,   theta~_p = <S alpha>_p
  !!
  !! The integrals use each particle's own domain: the particle point (MPM), or 2x2 Gauss
  !! points of the domain with weight 1/4 (uGIMP: the initial rectangle; CPDI: the current
  !! parallelogram), so a domain spanning several cells contributes to each. Gauss points
  !! lie strictly inside the domain (corner points of a regular seeding sit exactly on cell
  !! edges, which would make cell membership a rounding accident) and integrate the
  !! bilinear products in H exactly over a domain inside one cell.
  !!
  !! * cell: S = cell indicators. They are orthogonal at every quadrature point, so H is
  !!   diagonal (the mass of the cell) and alpha_c is the mass-weighted cell average.
  !! * nodal: S = bilinear nodal functions, H assembled by quadrature and solved with
  !!   LAPACK's banded Cholesky (dpbsv) on the active nodes (see `project_nodal`).
  !!
  !! Only particles in `mask` take part (fluids, and solids that opt in), so a cell shared
  !! with a non-participating solid is projected from the participating particles alone.
  !! The mass-weighted integral sum_p m_p theta_p is conserved exactly by both choices.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC, CPDI_ERR_LAPACK
  use cpdi_grid, only: grid_t
  use cpdi_particles, only: particles_t
  use cpdi_shape, only: SHAPE_MPM, SHAPE_GIMP
  implicit none
  private

  integer(ik), parameter, public :: PROJ_NONE = 0
  integer(ik), parameter, public :: PROJ_CELL = 1
  integer(ik), parameter, public :: PROJ_NODAL = 2
  real(wp), parameter :: GAUSS = 0.57735026918962576_wp   !! 1/sqrt(3)
  integer, parameter :: REFINE = 4                         !! iterative-refinement sweeps

  type, public :: projection_t
    !! Work storage, sized once per grid (nothing is allocated while stepping).
    real(wp), allocatable :: hd(:)       !! diagonal of H (cells) / lumped mass (nodes)
    real(wp), allocatable :: rhs(:)      !! int S^T theta dm, then alpha
    real(wp), allocatable :: band(:, :)  !! banded H (nodal)
    integer(ik), allocatable :: act(:)   !! node -> active index (nodal)
    integer(ik), allocatable :: node(:)  !! active index -> node (nodal)
  end type projection_t

  public :: projection_alloc, project_scalar, quadrature

  interface
    subroutine dpbtrf(uplo, n, kd, ab, ldab, info)
      import :: wp
      character(len=1), intent(in) :: uplo
      integer, intent(in) :: n, kd, ldab
      real(wp), intent(inout) :: ab(ldab, *)
      integer, intent(out) :: info
    end subroutine dpbtrf
    subroutine dpbtrs(uplo, n, kd, nrhs, ab, ldab, b, ldb, info)
      import :: wp
      character(len=1), intent(in) :: uplo
      integer, intent(in) :: n, kd, nrhs, ldab, ldb
      real(wp), intent(in) :: ab(ldab, *)
      real(wp), intent(inout) :: b(ldb, *)
      integer, intent(out) :: info
    end subroutine dpbtrs
  end interface

contains

  subroutine projection_alloc(pr, g, st)
    !! Size the work arrays for grid g.
    type(projection_t), intent(inout) :: pr
    type(grid_t), intent(in) :: g
    type(status_t), intent(inout) :: st
    integer :: ierr
    if (allocated(pr%hd)) deallocate (pr%hd, pr%rhs, pr%act, pr%node)
    allocate (pr%hd(g%nnodes), pr%rhs(g%nnodes), pr%act(g%nnodes), pr%node(g%nnodes), stat=ierr)
    if (ierr /= 0) call st%set(CPDI_ERR_ALLOC, 'could not allocate projection storage')
  end subroutine projection_alloc

  pure subroutine quadrature(shape, x, r, r0, nq, xq, wq)
    !! Quadrature points of one particle's domain.
    integer(ik), intent(in) :: shape
    real(wp), intent(in) :: x(2), r(4), r0(4)
    integer(ik), intent(out) :: nq
    real(wp), intent(out) :: xq(2, 4), wq(4)
    real(wp) :: a(2), b(2)
    select case (shape)
    case (SHAPE_MPM)
      nq = 1
      xq(:, 1) = x
      wq(1) = 1.0_wp
      return
    case (SHAPE_GIMP)
      a = [abs(r0(1)) + abs(r0(3)), 0.0_wp]
      b = [0.0_wp, abs(r0(2)) + abs(r0(4))]
    case default
      a = r(1:2)
      b = r(3:4)
    end select
    a = a*GAUSS
    b = b*GAUSS
    nq = 4
    xq(:, 1) = x - a - b
    xq(:, 2) = x + a - b
    xq(:, 3) = x + a + b
    xq(:, 4) = x - a + b
    wq = 0.25_wp
  end subroutine quadrature

  pure integer(ik) function cell_of(g, x)
    !! 1-based index of the padded-grid cell holding x (clamped to the grid).
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik) :: i, j
    i = min(max(int((x(1) - g%gorig(1))/g%h), 0), g%nn(1) - 2)
    j = min(max(int((x(2) - g%gorig(2))/g%h), 0), g%nn(2) - 2)
    cell_of = i + 1 + j*(g%nn(1) - 1)
  end function cell_of

  subroutine project_scalar(pr, mode, shape, g, p, mask, val, st)
    !! Replace val(p) of the particles in mask by its projection (mode PROJ_CELL or PROJ_NODAL).
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: mode, shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    type(status_t), intent(inout) :: st
    if (mode == PROJ_CELL) then
      call project_cell(pr, shape, g, p, mask, val)
    else if (mode == PROJ_NODAL) then
      call project_nodal(pr, shape, g, p, mask, val, st)
    end if
  end subroutine project_scalar

  subroutine project_cell(pr, shape, g, p, mask, val)
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    integer(ik) :: ip, q, nq, c
    real(wp) :: xq(2, 4), wq(4), mw, acc
    pr%hd = 0.0_wp
    pr%rhs = 0.0_wp
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, p%x(:, ip), p%r(:, ip), p%r0(:, ip), nq, xq, wq)
      do q = 1, nq
        c = cell_of(g, xq(:, q))
        mw = p%m(ip)*wq(q)
        pr%hd(c) = pr%hd(c) + mw
        pr%rhs(c) = pr%rhs(c) + mw*val(ip)
      end do
    end do
    where (pr%hd > 0.0_wp) pr%rhs = pr%rhs/pr%hd
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, p%x(:, ip), p%r(:, ip), p%r0(:, ip), nq, xq, wq)
      acc = 0.0_wp
      do q = 1, nq
        acc = acc + wq(q)*pr%rhs(cell_of(g, xq(:, q)))
      end do
      val(ip) = acc
    end do
  end subroutine project_cell

  subroutine project_nodal(pr, shape, g, p, mask, val, st)
    !! Consistent nodal projection: H_ij = sum_p m_p sum_q w_q N_i(x_q) N_j(x_q) on the
    !! active nodes (numbered along the shorter grid axis to keep the band narrow), solved
    !! by LAPACK's banded Cholesky (dpbtrf/dpbtrs). Point quadrature can leave H singular
    !! on fields that vanish at all quadrature points; those fields do not change any
    !! projected particle value. A relative shift eps = 1e-12 of the diagonal makes the
    !! factorisation safe, and iterative refinement, alpha <- alpha + (H + eps I)^-1 eps alpha,
    !! removes the shift's effect on the range of H.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, q, nq, a, b, ka(4), na, kd, ia, ib, info, ierr, k, n1, n2, it
    real(wp) :: xq(2, 4), wq(4), nv(4), mw, acc, shift
    logical :: xmajor
    character(len=120) :: buf

    n1 = g%nn(1)
    n2 = g%nn(2)
    xmajor = n1 <= n2        ! number nodes so the band width is the shorter row
    ! active nodes
    pr%act = 0
    pr%hd = 0.0_wp
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, p%x(:, ip), p%r(:, ip), p%r0(:, ip), nq, xq, wq)
      do q = 1, nq
        call corner_nodes(g, xq(:, q), ka, nv)
        pr%hd(ka) = pr%hd(ka) + p%m(ip)*wq(q)*nv
      end do
    end do
    na = 0
    do k = 1, g%nnodes
      b = reorder(k)
      if (pr%hd(b) > 0.0_wp) then
        na = na + 1
        pr%act(b) = na
        pr%node(na) = b
      end if
    end do
    if (na == 0) return
    kd = 0
    do ia = 1, na
      k = pr%node(ia)
      kd = max(kd, maxval(pr%act(neighbours(k)), mask=pr%act(neighbours(k)) > 0) - ia)
    end do
    kd = max(kd, 1)
    if (allocated(pr%band)) then
      if (size(pr%band, 1) < kd + 1 .or. size(pr%band, 2) < na) deallocate (pr%band)
    end if
    if (.not. allocated(pr%band)) then
      allocate (pr%band(kd + 1, na), stat=ierr)
      if (ierr /= 0) then
        call st%set(CPDI_ERR_ALLOC, 'could not allocate the banded projection matrix; use projection = "cell"')
        return
      end if
    end if
    pr%band(1:kd + 1, 1:na) = 0.0_wp
    pr%rhs(1:na) = 0.0_wp
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, p%x(:, ip), p%r(:, ip), p%r0(:, ip), nq, xq, wq)
      do q = 1, nq
        call corner_nodes(g, xq(:, q), ka, nv)
        mw = p%m(ip)*wq(q)
        do a = 1, 4
          ia = pr%act(ka(a))
          if (ia == 0) cycle          ! node reached with zero weight only
          pr%rhs(ia) = pr%rhs(ia) + mw*nv(a)*val(ip)
          do b = 1, 4
            ib = pr%act(ka(b))
            if (ib < ia) cycle        ! also skips inactive (0) nodes
            ! upper band storage: band(kd + 1 + ia - ib, ib) = H(ia, ib), ia <= ib
            pr%band(kd + 1 + ia - ib, ib) = pr%band(kd + 1 + ia - ib, ib) + mw*nv(a)*nv(b)
          end do
        end do
      end do
    end do
    shift = 1.0e-12_wp*maxval(pr%band(kd + 1, 1:na))
    pr%band(kd + 1, 1:na) = pr%band(kd + 1, 1:na) + shift
    call dpbtrf('U', na, kd, pr%band, size(pr%band, 1), info)
    if (info == 0) call dpbtrs('U', na, kd, 1, pr%band, size(pr%band, 1), pr%rhs, na, info)
    do it = 1, REFINE
      if (info /= 0) exit
      pr%hd(1:na) = shift*pr%rhs(1:na)         ! residual of H alpha = b is eps alpha
      call dpbtrs('U', na, kd, 1, pr%band, size(pr%band, 1), pr%hd, na, info)
      pr%rhs(1:na) = pr%rhs(1:na) + pr%hd(1:na)
    end do
    if (info /= 0) then
      write (buf, '(a,i0,a)') 'nodal projection: banded Cholesky failed (info = ', info, '); use projection = "cell"'
      call st%set(CPDI_ERR_LAPACK, trim(buf))
      return
    end if
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, p%x(:, ip), p%r(:, ip), p%r0(:, ip), nq, xq, wq)
      acc = 0.0_wp
      do q = 1, nq
        call corner_nodes(g, xq(:, q), ka, nv)
        do a = 1, 4
          if (pr%act(ka(a)) > 0) acc = acc + wq(q)*nv(a)*pr%rhs(pr%act(ka(a)))
        end do
      end do
      val(ip) = acc
    end do

  contains

    pure integer(ik) function reorder(k)
      !! k-th node in the numbering along the shorter axis.
      integer(ik), intent(in) :: k
      if (xmajor) then
        reorder = k
      else
        reorder = 1 + (k - 1)/n2 + mod(k - 1, n2)*n1
      end if
    end function reorder

    pure function neighbours(k) result(nb)
      !! Nodes sharing a cell with node k (3x3 block, clamped to the grid).
      integer(ik), intent(in) :: k
      integer(ik) :: nb(9), i, j, di, dj, m
      i = mod(k - 1, n1)
      j = (k - 1)/n1
      m = 0
      do dj = -1, 1
        do di = -1, 1
          m = m + 1
          nb(m) = 1 + min(max(i + di, 0), n1 - 1) + min(max(j + dj, 0), n2 - 1)*n1
        end do
      end do
    end function neighbours
  end subroutine project_nodal

  pure subroutine corner_nodes(g, x, k, nv)
    !! The 4 nodes of the cell holding x and their bilinear values.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: x(2)
    integer(ik), intent(out) :: k(4)
    real(wp), intent(out) :: nv(4)
    real(wp) :: s1, s2, xi, eta
    integer(ik) :: i0, j0, base
    s1 = (x(1) - g%gorig(1))/g%h
    s2 = (x(2) - g%gorig(2))/g%h
    i0 = min(max(int(s1), 0), g%nn(1) - 2)
    j0 = min(max(int(s2), 0), g%nn(2) - 2)
    xi = min(max(s1 - real(i0, wp), 0.0_wp), 1.0_wp)
    eta = min(max(s2 - real(j0, wp), 0.0_wp), 1.0_wp)
    base = i0 + 1 + j0*g%nn(1)
    k = [base, base + 1, base + g%nn(1), base + g%nn(1) + 1]
    nv = [(1.0_wp - xi)*(1.0_wp - eta), xi*(1.0_wp - eta), (1.0_wp - xi)*eta, xi*eta]
  end subroutine corner_nodes
end module cpdi_projection
