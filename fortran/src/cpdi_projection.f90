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
  !!
  !! The operator (quadrature cells, H and, for nodal, its Cholesky factor) depends only
  !! on the configuration, so it is built once (`projection_setup`) and applied to several
  !! fields (`projection_apply`): a step projects its volumetric strain increment and its
  !! mean stress with the operator of the configuration at the start of the step, the one
  !! its shape functions were formed in. The cell scatters run on OpenMP through
  !! two-colour strips (cpdi_schedule), bitwise the same at any thread count; the nodal
  !! assembly and solve are serial.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC, CPDI_ERR_LAPACK, CPDI_ERR_STATE
  use cpdi_grid, only: grid_t
  use cpdi_particles, only: particles_t
  use cpdi_shape, only: SHAPE_MPM, SHAPE_GIMP
  use cpdi_schedule, only: strips_t, strips_alloc, strips_build, NCHUNK, chunk_range, blocks_t, block_start, &
                           strip_start, block_next
  implicit none
  private

  integer(ik), parameter, public :: PROJ_NONE = 0
  integer(ik), parameter, public :: PROJ_CELL = 1
  integer(ik), parameter, public :: PROJ_NODAL = 2
  real(wp), parameter :: GAUSS = 0.57735026918962576_wp   !! 1/sqrt(3)
  integer, parameter :: REFINE = 4                         !! iterative-refinement sweeps

  type, public :: projection_t
    !! Operator and work storage, sized once per grid and particle count (nothing is
    !! allocated while stepping, except the nodal band when the active set outgrows it).
    integer(ik) :: mode = 0              !! PROJ_CELL or PROJ_NODAL of the current operator
    real(wp), allocatable :: hd(:)       !! 1 / diagonal of H (cells) / lumped mass (nodes)
    real(wp), allocatable :: rhs(:)      !! int S^T theta dm, then alpha
    real(wp), allocatable :: res(:)      !! refinement correction (nodal)
    real(wp), allocatable :: band(:, :)  !! banded Cholesky factor of H (nodal)
    integer(ik), allocatable :: act(:)   !! node -> active index (nodal)
    integer(ik), allocatable :: node(:)  !! active index -> node (nodal)
    integer(ik), allocatable :: qc(:, :) !! cell of each quadrature point (4, n) (cell)
    integer(ik), allocatable :: row(:)   !! first cell row of each particle (cell)
    real(wp), allocatable :: xs(:, :)    !! positions the nodal operator was built at (2, n)
    real(wp), allocatable :: rs(:, :)    !! domains the nodal operator was built at (4, n)
    integer(ik) :: nq = 4                !! quadrature points per particle
    integer(ik) :: na = 0                !! active nodes (nodal)
    integer(ik) :: kd = 1                !! half band width (nodal)
    real(wp) :: shift = 0.0_wp           !! diagonal shift of the factorisation (nodal)
    type(strips_t) :: sp                 !! own scatter colouring of the cell assembly
    logical :: own = .true.              !! cell scatters use sp (no colouring was given)
    logical :: massed = .false.          !! hd holds the cell masses of this operator
    integer(ik) :: cspan(NCHUNK) = 1     !! per block: tallest span of cell rows (setup_cell)
    integer(ik) :: crange(2, NCHUNK) = 0 !! per block: first and last cell of the rows of its quadrature points
  end type projection_t

  public :: projection_alloc, projection_setup, projection_apply, project_scalar, quadrature

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

  subroutine projection_alloc(pr, g, n, st)
    !! Size the work arrays for grid g and n particles.
    type(projection_t), intent(inout) :: pr
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: n
    type(status_t), intent(inout) :: st
    integer :: ierr
    if (allocated(pr%hd)) deallocate (pr%hd, pr%rhs, pr%qc, pr%row)
    if (allocated(pr%xs)) deallocate (pr%xs, pr%rs)
    if (allocated(pr%res)) deallocate (pr%res, pr%act, pr%node)
    allocate (pr%hd(g%nnodes), pr%rhs(g%nnodes), pr%qc(4, n), pr%row(n), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate projection storage; use fewer particles')
      return
    end if
    call strips_alloc(pr%sp, n, g%nn(2), st)
    pr%mode = 0
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
      xq(:, 2:4) = 0.0_wp
      wq = [1.0_wp, 0.0_wp, 0.0_wp, 0.0_wp]
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

  subroutine projection_setup(pr, mode, shape, g, p, mask, st, sp)
    !! Build the operator of the current configuration for mode PROJ_CELL or PROJ_NODAL.
    !! sp: a two-colour scatter colouring of the particles whose stencils hold every cell
    !! their quadrature points fall in (the shape functions' strips of this configuration);
    !! the cell operator then scatters by it instead of building its own.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: mode, shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    type(status_t), intent(inout) :: st
    type(strips_t), intent(in), optional :: sp
    ! Orphaned worksharing: every thread of the step's parallel region calls this (and
    ! projection_apply); outside a parallel region they run serially.
    if (mode == PROJ_CELL) then
      call setup_cell(pr, shape, g, p, .not. present(sp))
    else if (mode == PROJ_NODAL) then
      !$omp single
      call setup_nodal(pr, shape, g, p, mask, st)
      !$omp end single
    end if
    !$omp single
    pr%mode = mode
    !$omp end single
  end subroutine projection_setup

  subroutine projection_apply(pr, shape, g, p, mask, val, st, sp)
    !! Replace val(p) of the particles in mask by its projection with the current operator;
    !! sp: the colouring given to projection_setup, if one was.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    type(status_t), intent(inout) :: st
    type(strips_t), intent(in), optional :: sp
    if (pr%mode == PROJ_CELL) then
      if (pr%own) then
        call apply_cell(pr, pr%sp, p, mask, val)
      else if (present(sp)) then
        call apply_cell(pr, sp, p, mask, val)
      else
        !$omp single
        call st%set(CPDI_ERR_STATE, 'projection_apply: the operator was set up with a colouring; pass it')
        !$omp end single
      end if
    else if (pr%mode == PROJ_NODAL) then
      call apply_nodal(pr, shape, g, p, mask, val, st)
    end if
  end subroutine projection_apply

  subroutine project_scalar(pr, mode, shape, g, p, mask, val, st)
    !! Set up the operator of the current configuration and project val with it.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: mode, shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    type(status_t), intent(inout) :: st
    call projection_setup(pr, mode, shape, g, p, mask, st)
    if (st%ok()) call projection_apply(pr, shape, g, p, mask, val, st)
  end subroutine project_scalar

  subroutine setup_cell(pr, shape, g, p, own)
    !! Cell of every quadrature point and, when the operator has no scatter colouring
    !! given (own), its own strips. The cell masses are summed by the first apply, in the
    !! same pass as its field.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: own
    integer(ik) :: c, lo, hi, rmin, rmax
    type(blocks_t) :: blk
    !$omp single
    pr%nq = merge(1_ik, 4_ik, shape == SHAPE_MPM)
    pr%own = own
    pr%massed = .false.
    !$omp end single
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, p%n, lo, hi)
      pr%cspan(c) = 1
      rmin = huge(1_ik)
      rmax = -1
      call locate_block(lo, hi, shape, p%x, p%r, p%r0, g%gorig, 1.0_wp/g%h, g%nn, pr%qc, pr%row, pr%cspan(c), &
                        rmin, rmax)
      pr%crange(:, c) = [huge(1_ik), 0_ik]   ! the block's cells: whole rows rmin..rmax
      if (rmax >= rmin) pr%crange(:, c) = [rmin*(g%nn(1) - 1) + 1, (rmax + 1)*(g%nn(1) - 1)]
    end do
    !$omp barrier
    if (own) call strips_build(pr%sp, pr%row, maxval(pr%cspan))
  end subroutine setup_cell

  subroutine locate_block(lo, hi, shape, x, r, r0, gorig, rh, nn, qc, row, span, rmin, rmax)
    !! Cells of the quadrature points of particles lo..hi (plain arrays), their lowest
    !! cell row, the running tallest span of rows and the running lowest and highest row.
    integer(ik), intent(in) :: lo, hi, shape, nn(2)
    real(wp), intent(in) :: x(2, *), r(4, *), r0(4, *), gorig(2), rh
    integer(ik), intent(inout) :: qc(4, *), row(*), span, rmin, rmax
    integer(ik) :: ip, q, nq, i, j, jmin, jmax
    real(wp) :: xq(2, 4), wq(4)
    do ip = lo, hi
      call quadrature(shape, x(:, ip), r(:, ip), r0(:, ip), nq, xq, wq)
      jmin = huge(1_ik)
      jmax = 0
      do q = 1, nq
        i = min(max(int((xq(1, q) - gorig(1))*rh), 0), nn(1) - 2)
        j = min(max(int((xq(2, q) - gorig(2))*rh), 0), nn(2) - 2)
        qc(q, ip) = i + 1 + j*(nn(1) - 1)
        jmin = min(jmin, j)
        jmax = max(jmax, j)
      end do
      row(ip) = jmin
      span = max(span, jmax - jmin + 1)
      rmin = min(rmin, jmin)
      rmax = max(rmax, jmax)
    end do
  end subroutine locate_block

  subroutine scatter_cell(pr, sp, p, mask, val, acc, mass)
    !! acc(c) = sum over quadrature points in cell c of w_q m_p val_p (and, if present,
    !! mass(c) = sum of w_q m_p), by the two-colour strips sp: bitwise the same at any
    !! thread count. Only the cells of the rows from the lowest to the highest one holding a
    !! quadrature point are cleared and summed (the gathers read no other); the rest keep old values.
    type(projection_t), intent(in) :: pr
    type(strips_t), intent(in) :: sp
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(in) :: val(:)
    real(wp), intent(inout) :: acc(:)
    real(wp), intent(inout), optional :: mass(:)
    integer(ik) :: colour, b, c, c0, c1
    real(wp) :: wq
    type(blocks_t) :: blk
    wq = 1.0_wp/real(pr%nq, wp)
    c0 = max(1_ik, minval(pr%crange(1, :)))
    c1 = min(size(acc, kind=ik), maxval(pr%crange(2, :)))
    !$omp do schedule(static) private(c)
    do c = c0, c1
      acc(c) = 0.0_wp
    end do
    !$omp end do nowait
    if (present(mass)) then
      !$omp do schedule(static) private(c)
      do c = c0, c1
        mass(c) = 0.0_wp
      end do
      !$omp end do nowait
    end if
    !$omp barrier
    do colour = 1, 2
      call strip_start(blk, sp, colour)
      do while (block_next(blk, b))
        if (present(mass)) then
          call scatter_strip_mass(sp%perm(sp%start(b):sp%start(b + 1) - 1), pr%nq, pr%qc, p%m, mask, wq, val, &
                                  acc, mass)
        else
          call scatter_strip(sp%perm(sp%start(b):sp%start(b + 1) - 1), pr%nq, pr%qc, p%m, mask, wq, val, acc)
        end if
      end do
      !$omp barrier
    end do
    if (.not. present(mass)) return
    !$omp do schedule(static) private(c)
    do c = c0, c1
      if (mass(c) > 0.0_wp) mass(c) = 1.0_wp/mass(c)   ! stored as 1 / mass
    end do
    !$omp end do
  end subroutine scatter_cell

  subroutine scatter_strip(perm, nq, qc, pm, mask, wq, val, acc)
    !! One strip of scatter_cell, on plain arrays.
    integer(ik), intent(in) :: perm(:), nq, qc(4, *)
    real(wp), intent(in) :: pm(*), wq, val(:)
    logical, intent(in) :: mask(*)
    real(wp), intent(inout) :: acc(*)
    integer(ik) :: i, ip, q
    real(wp) :: mw
    do i = 1, size(perm)
      ip = perm(i)
      if (.not. mask(ip)) cycle
      mw = pm(ip)*wq*val(ip)
      do q = 1, nq
        acc(qc(q, ip)) = acc(qc(q, ip)) + mw
      end do
    end do
  end subroutine scatter_strip

  subroutine scatter_strip_mass(perm, nq, qc, pm, mask, wq, val, acc, mass)
    !! scatter_strip that also sums the cell masses.
    integer(ik), intent(in) :: perm(:), nq, qc(4, *)
    real(wp), intent(in) :: pm(*), wq, val(:)
    logical, intent(in) :: mask(*)
    real(wp), intent(inout) :: acc(*), mass(*)
    integer(ik) :: i, ip, q
    real(wp) :: mw
    do i = 1, size(perm)
      ip = perm(i)
      if (.not. mask(ip)) cycle
      mw = pm(ip)*wq
      do q = 1, nq
        mass(qc(q, ip)) = mass(qc(q, ip)) + mw
        acc(qc(q, ip)) = acc(qc(q, ip)) + mw*val(ip)
      end do
    end do
  end subroutine scatter_strip_mass

  subroutine apply_cell(pr, sp, p, mask, val)
    !! Mass-weighted cell averages of val, gathered back to the quadrature points (the
    !! first apply of an operator also sums its cell masses).
    type(projection_t), intent(inout) :: pr
    type(strips_t), intent(in) :: sp
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    integer(ik) :: c, lo, hi
    type(blocks_t) :: blk
    if (pr%massed) then
      call scatter_cell(pr, sp, p, mask, val, pr%rhs)
    else
      call scatter_cell(pr, sp, p, mask, val, pr%rhs, pr%hd)
      !$omp single
      pr%massed = .true.
      !$omp end single nowait
    end if
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, p%n, lo, hi)
      call gather_block(lo, hi, pr%nq, pr%qc, mask, pr%rhs, pr%hd, val)
    end do
    !$omp barrier
  end subroutine apply_cell

  subroutine gather_block(lo, hi, nq, qc, mask, rhs, rhd, val)
    !! val_p = sum_q w_q rhs(c_q) / m(c_q) for particles lo..hi, plain arrays.
    integer(ik), intent(in) :: lo, hi, nq, qc(4, *)
    logical, intent(in) :: mask(*)
    real(wp), intent(in) :: rhs(*), rhd(*)
    real(wp), intent(inout) :: val(:)
    integer(ik) :: ip, q
    real(wp) :: acc, wq
    wq = 1.0_wp/real(nq, wp)
    do ip = lo, hi
      if (.not. mask(ip)) cycle
      acc = 0.0_wp
      do q = 1, nq
        acc = acc + wq*(rhs(qc(q, ip))*rhd(qc(q, ip)))
      end do
      val(ip) = acc
    end do
  end subroutine gather_block

  subroutine setup_nodal(pr, shape, g, p, mask, st)
    !! Consistent nodal projection: H_ij = sum_p m_p sum_q w_q N_i(x_q) N_j(x_q) on the
    !! active nodes (numbered along the shorter grid axis to keep the band narrow), factored
    !! by LAPACK's banded Cholesky (dpbtrf). Point quadrature can leave H singular on
    !! fields that vanish at all quadrature points; those fields do not change any
    !! projected particle value. A relative shift eps = 1e-12 of the diagonal makes the
    !! factorisation safe, and iterative refinement in `apply_nodal` removes the shift's
    !! effect on the range of H.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, q, nq, a, b, ka(4), na, kd, ia, ib, info, ierr, k, n1, n2
    real(wp) :: xq(2, 4), wq(4), nv(4), mw
    logical :: xmajor
    character(len=120) :: buf

    n1 = g%nn(1)
    n2 = g%nn(2)
    xmajor = n1 <= n2        ! number nodes so the band width is the shorter row
    ! nodal work arrays and the configuration of the operator (first nodal use only)
    if (.not. allocated(pr%res)) then
      allocate (pr%res(g%nnodes), pr%act(g%nnodes), pr%node(g%nnodes), stat=ierr)
      if (ierr /= 0) then
        call st%set(CPDI_ERR_ALLOC, 'could not allocate the nodal projection storage; use projection = "cell"')
        return
      end if
    end if
    if (allocated(pr%xs)) then
      if (size(pr%xs, 2) /= p%n) deallocate (pr%xs, pr%rs)
    end if
    if (.not. allocated(pr%xs)) then
      allocate (pr%xs(2, p%n), pr%rs(4, p%n), stat=ierr)
      if (ierr /= 0) then
        call st%set(CPDI_ERR_ALLOC, 'could not allocate the nodal projection storage; use projection = "cell"')
        return
      end if
    end if
    pr%xs = p%x(:, 1:p%n)
    pr%rs = p%r(:, 1:p%n)
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
    pr%na = na
    if (na == 0) return
    kd = 0
    do ia = 1, na
      k = pr%node(ia)
      kd = max(kd, maxval(pr%act(neighbours(k)), mask=pr%act(neighbours(k)) > 0) - ia)
    end do
    kd = max(kd, 1)
    pr%kd = kd
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
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, p%x(:, ip), p%r(:, ip), p%r0(:, ip), nq, xq, wq)
      do q = 1, nq
        call corner_nodes(g, xq(:, q), ka, nv)
        mw = p%m(ip)*wq(q)
        do a = 1, 4
          ia = pr%act(ka(a))
          if (ia == 0) cycle          ! node reached with zero weight only
          do b = 1, 4
            ib = pr%act(ka(b))
            if (ib < ia) cycle        ! also skips inactive (0) nodes
            ! upper band storage: band(kd + 1 + ia - ib, ib) = H(ia, ib), ia <= ib
            pr%band(kd + 1 + ia - ib, ib) = pr%band(kd + 1 + ia - ib, ib) + mw*nv(a)*nv(b)
          end do
        end do
      end do
    end do
    pr%shift = 1.0e-12_wp*maxval(pr%band(kd + 1, 1:na))
    pr%band(kd + 1, 1:na) = pr%band(kd + 1, 1:na) + pr%shift
    call dpbtrf('U', na, kd, pr%band, size(pr%band, 1), info)
    if (info /= 0) then
      write (buf, '(a,i0,a)') 'nodal projection: banded Cholesky failed (info = ', info, '); use projection = "cell"'
      call st%set(CPDI_ERR_LAPACK, trim(buf))
    end if

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
  end subroutine setup_nodal

  subroutine apply_nodal(pr, shape, g, p, mask, val, st)
    !! Solve (H + eps I) alpha = int S^T val dm with the stored factor, refine
    !! (alpha <- alpha + (H + eps I)^-1 eps alpha, REFINE sweeps), and evaluate at the
    !! quadrature points, all in the configuration the operator was built in.
    type(projection_t), intent(inout) :: pr
    integer(ik), intent(in) :: shape
    type(grid_t), intent(in) :: g
    type(particles_t), intent(in) :: p
    logical, intent(in) :: mask(:)
    real(wp), intent(inout) :: val(:)
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, q, nq, a, ka(4), ia, info, na, it, c, lo, hi
    type(blocks_t) :: blk
    real(wp) :: xq(2, 4), wq(4), nv(4), mw, acc
    character(len=120) :: buf
    logical :: ok

    na = pr%na
    if (na == 0) return
    !$omp single
    pr%rhs(1:na) = 0.0_wp
    do ip = 1, p%n
      if (.not. mask(ip)) cycle
      call quadrature(shape, pr%xs(:, ip), pr%rs(:, ip), p%r0(:, ip), nq, xq, wq)
      do q = 1, nq
        call corner_nodes(g, xq(:, q), ka, nv)
        mw = p%m(ip)*wq(q)*val(ip)
        do a = 1, 4
          ia = pr%act(ka(a))
          if (ia > 0) pr%rhs(ia) = pr%rhs(ia) + mw*nv(a)
        end do
      end do
    end do
    call dpbtrs('U', na, pr%kd, 1, pr%band, size(pr%band, 1), pr%rhs, na, info)
    do it = 1, REFINE
      if (info /= 0) exit
      pr%res(1:na) = pr%shift*pr%rhs(1:na)      ! residual of H alpha = b is eps alpha
      call dpbtrs('U', na, pr%kd, 1, pr%band, size(pr%band, 1), pr%res, na, info)
      pr%rhs(1:na) = pr%rhs(1:na) + pr%res(1:na)
    end do
    if (info /= 0) then
      write (buf, '(a,i0,a)') 'nodal projection: banded solve failed (info = ', info, '); use projection = "cell"'
      call st%set(CPDI_ERR_LAPACK, trim(buf))
    end if
    ok = st%ok()
    !$omp end single copyprivate(ok)
    if (.not. ok) return   ! (broadcast: st was set by the single's thread)
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, p%n, lo, hi)
      do ip = lo, hi
        if (.not. mask(ip)) cycle
        call quadrature(shape, pr%xs(:, ip), pr%rs(:, ip), p%r0(:, ip), nq, xq, wq)
        acc = 0.0_wp
        do q = 1, nq
          call corner_nodes(g, xq(:, q), ka, nv)
          do a = 1, 4
            if (pr%act(ka(a)) > 0) acc = acc + wq(q)*nv(a)*pr%rhs(pr%act(ka(a)))
          end do
        end do
        val(ip) = acc
      end do
    end do
    !$omp barrier
  end subroutine apply_nodal

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
