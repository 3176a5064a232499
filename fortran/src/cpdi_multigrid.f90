!> Geometric multigrid V-cycle on the cell-centred pressure grid: a preconditioner of the CG.
module cpdi_multigrid
  !! One V-cycle approximates A^-1 r for the 5-point pressure operator of cpdi_pressure
  !! (diagonal adiag, couplings ai to the right and aj to the top; any symmetric positive
  !! (semi-)definite 5-point matrix: ghost-fluid surface, mixture face coefficients, the
  !! boundary-flux operator of cpdi_coupling). After McAdams, Sifakis & Teran (2010), in 2D
  !! and with the fine operator's own coefficients on every level:
  !!
  !! * **Levels.** Level 1 is the physical cells of the MAC grid; level l + 1 merges 2 x 2 cells
  !!   of level l (an odd count leaves a last cell with one child and the ring); the hierarchy
  !!   ends when both counts are at most 2. Each level has a ring of one cell around it. A cell is
  !!   active (an unknown) if any child is; an inactive cell is Dirichlet (air: value 0) if any
  !!   child is, else Neumann (a wall: no value).
  !! * **Coarse operators** from the fine one's coefficients, A_c = (1/2) P0^T A P0 with P0 the
  !!   piecewise-constant injection: a coarse coupling is the mean of the two fine couplings
  !!   across its face, the diagonal half the children's diagonals plus their internal couplings.
  !!   For the 5-point Laplacian this is the same Laplacian on the coarse cells (2D: h-free), a
  !!   surface at theta h keeps its flux, and A_c stays symmetric and 5-point on every level.
  !! * **Transfers.** Prolongation P: bilinear between cell centres (weights 9, 3, 3, 1 of the
  !!   parent, its two nearer neighbours and the diagonal one), a Dirichlet neighbour counting as
  !!   0 and a Neumann one left out (weights renormalised: a constant is kept next to a wall).
  !!   Restriction R = P^T exactly (the same weights, gathered), so R sums about four fine
  !!   residuals, matching A_c's scale.
  !! * **Smoother.** Red-black Gauss-Seidel: NSMOOTH sweeps red then black before the coarse
  !!   correction, NSMOOTH sweeps black then red after it (the adjoint order); the coarsest level
  !!   takes NCOARSE pairs of a forward and a backward sweep. The sweep sequence is a palindrome
  !!   and R = P^T, so the V-cycle is a symmetric operator, positive definite for a positive
  !!   definite A (each half-sweep is an exact solve on one colour, and the two colours cover
  !!   every cell): a valid CG preconditioner. A singular A (closed water, cpdi_pressure) gives
  !!   a symmetric operator positive on A's range, which is where the CG iterates live.
  !!
  !! Every cell's update reads only the other colour (or the previous level), so threading the
  !! row loops changes no bit of the result at any thread count. Storage is allocated once
  !! (mg_alloc); mg_build and mg_vcycle allocate nothing.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  implicit none
  private

  integer(ik), parameter, public :: MG_DIRICHLET = 0  !! inactive cell, value 0 (air)
  integer(ik), parameter, public :: MG_ACTIVE = 1     !! an unknown
  integer(ik), parameter, public :: MG_NEUMANN = 2    !! inactive cell without a value (wall)
  integer(ik), parameter :: MAXLEV = 40               !! most levels (2^40 cells a side)
  integer(ik), parameter :: NSMOOTH = 2               !! red-black sweeps before and after a coarse correction
  integer(ik), parameter :: NCOARSE = 8               !! forward + backward sweep pairs on the coarsest level
  integer(ik), parameter :: PAR_MIN = 8192            !! cells of a level below which its loops run on one thread

  type, public :: mg_t
    !! The level hierarchy. Cell (i, j) of level l, i = 0..nx(l) + 1, j = 0..ny(l) + 1 (the ring
    !! included), is entry off(l) + i + j (nx(l) + 2) of the arrays.
    integer(ik) :: nlev = 0                      !! levels
    integer(ik) :: nx(MAXLEV) = 0, ny(MAXLEV) = 0, off(MAXLEV) = 0
    integer(ik) :: roff(MAXLEV) = 0              !! row j of level l: entry roff(l) + j of ilo, ihi
    integer(ik), allocatable :: ilo(:), ihi(:)   !! per row: first and last active cell (ilo > ihi: none)
    integer(ik), allocatable :: kind(:)          !! MG_ACTIVE, MG_DIRICHLET or MG_NEUMANN
    real(wp), allocatable :: ad(:)               !! diagonal
    real(wp), allocatable :: di(:)               !! 1 / diagonal (0 where the diagonal is not positive)
    real(wp), allocatable :: ae(:), an(:)        !! couplings to the right and to the top neighbour
    real(wp), allocatable :: wn(:)               !! 1 / (sum of a cell's prolongation weights) [16ths]
    real(wp), allocatable :: x(:), b(:), t(:)    !! solution, right-hand side, residual
  end type mg_t

  public :: mg_alloc, mg_build, mg_apply

contains

  pure integer(ik) function at(mg, l, i, j)
    !! Entry of cell (i, j) of level l.
    type(mg_t), intent(in) :: mg
    integer(ik), intent(in) :: l, i, j
    at = mg%off(l) + i + j*(mg%nx(l) + 2)
  end function at

  subroutine mg_alloc(mg, nx, ny, st)
    !! Levels and storage for nx x ny fine cells.
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: nx, ny
    type(status_t), intent(inout) :: st
    integer(ik) :: l, n
    integer :: ierr
    if (allocated(mg%kind)) deallocate (mg%kind, mg%ad, mg%di, mg%ae, mg%an, mg%wn, mg%x, mg%b, mg%t, mg%ilo, mg%ihi)
    mg%nx = 0
    mg%ny = 0
    mg%off = 0
    mg%roff = 0
    l = 1
    mg%nx(1) = max(nx, 1_ik)
    mg%ny(1) = max(ny, 1_ik)
    mg%off(1) = 1
    do while (max(mg%nx(l), mg%ny(l)) > 2 .and. l < MAXLEV)
      mg%off(l + 1) = mg%off(l) + (mg%nx(l) + 2)*(mg%ny(l) + 2)
      mg%roff(l + 1) = mg%roff(l) + mg%ny(l) + 2
      mg%nx(l + 1) = (mg%nx(l) + 1)/2
      mg%ny(l + 1) = (mg%ny(l) + 1)/2
      l = l + 1
    end do
    mg%nlev = l
    n = mg%off(l) + (mg%nx(l) + 2)*(mg%ny(l) + 2) - 1
    allocate (mg%kind(n), mg%ad(n), mg%di(n), mg%ae(n), mg%an(n), mg%wn(n), mg%x(n), mg%b(n), mg%t(n), &
              mg%ilo(mg%roff(l) + mg%ny(l) + 2), mg%ihi(mg%roff(l) + mg%ny(l) + 2), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the multigrid levels; use a larger cell size')
      mg%nlev = 0
      return
    end if
    mg%kind = MG_NEUMANN
    mg%ad = 0.0_wp
    mg%di = 0.0_wp
    mg%ae = 0.0_wp
    mg%an = 0.0_wp
    mg%wn = 0.0_wp
    mg%x = 0.0_wp
    mg%b = 0.0_wp
    mg%t = 0.0_wp
    mg%ilo = 1
    mg%ihi = 0
  end subroutine mg_alloc

  subroutine mg_build(mg, base, n1, cell, fluid, air, adiag, ai, aj)
    !! The hierarchy for the fine operator (adiag, ai, aj) of a lattice whose rows are n1 long:
    !! level 1's cell (i, j), ring included, is lattice entry base + i + j n1; its kind is
    !! MG_ACTIVE where cell = fluid, MG_DIRICHLET where cell = air, else MG_NEUMANN. The couplings
    !! of a non-fluid cell, and those towards one, must be zero.
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: base, n1, fluid, air
    integer(ik), intent(in) :: cell(:)
    real(wp), intent(in) :: adiag(:), ai(:), aj(:)
    integer(ik) :: l, i, j, c, k
    !$omp parallel do if (mg%nx(1)*mg%ny(1) > PAR_MIN) default(shared) private(i, c, k)
    do j = 0, mg%ny(1) + 1
      do i = 0, mg%nx(1) + 1
        c = base + i + j*n1
        k = at(mg, 1_ik, i, j)
        mg%ad(k) = 0.0_wp
        mg%ae(k) = 0.0_wp
        mg%an(k) = 0.0_wp
        if (cell(c) == fluid .and. i >= 1 .and. j >= 1 .and. i <= mg%nx(1) .and. j <= mg%ny(1)) then
          mg%kind(k) = MG_ACTIVE
          mg%ad(k) = adiag(c)
          if (i < mg%nx(1)) mg%ae(k) = ai(c)
          if (j < mg%ny(1)) mg%an(k) = aj(c)
        else if (cell(c) == air .or. cell(c) == fluid) then
          mg%kind(k) = MG_DIRICHLET
        else
          mg%kind(k) = MG_NEUMANN
        end if
      end do
    end do
    !$omp end parallel do
    call inverse_diagonal(mg, 1_ik)
    call row_ranges(mg, 1_ik)
    do l = 1, mg%nlev - 1
      call coarsen(mg, l)
      call inverse_diagonal(mg, l + 1)
      call row_ranges(mg, l + 1)
      call weights(mg, l)
    end do
  end subroutine mg_build

  subroutine row_ranges(mg, l)
    !! ilo, ihi of level l's rows: the loops of a V-cycle visit only the span of active cells of
    !! each row (a dam break's water fills a tenth of its grid).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: i, j, k0
    do j = 1, mg%ny(l)
      k0 = at(mg, l, 0_ik, j)
      mg%ilo(mg%roff(l) + j) = mg%nx(l) + 1
      mg%ihi(mg%roff(l) + j) = 0
      do i = 1, mg%nx(l)
        if (mg%kind(k0 + i) == MG_ACTIVE) then
          mg%ilo(mg%roff(l) + j) = min(mg%ilo(mg%roff(l) + j), i)
          mg%ihi(mg%roff(l) + j) = i
        end if
      end do
    end do
  end subroutine row_ranges

  subroutine mg_apply(mg, base, n1, r, z)
    !! z = V r: one V-cycle for the lattice of mg_build (r read and z written on level 1's active
    !! cells; z = 0 on its other cells).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: base, n1
    real(wp), intent(in) :: r(:)
    real(wp), intent(inout) :: z(:)
    integer(ik) :: i, j, k
    !$omp parallel do if (mg%nx(1)*mg%ny(1) > PAR_MIN) default(shared) private(i, k)
    do j = 1, mg%ny(1)
      do i = 1, mg%nx(1)
        k = at(mg, 1_ik, i, j)
        mg%b(k) = 0.0_wp
        if (mg%kind(k) == MG_ACTIVE) mg%b(k) = r(base + i + j*n1)
      end do
    end do
    !$omp end parallel do
    call mg_vcycle(mg)
    !$omp parallel do if (mg%nx(1)*mg%ny(1) > PAR_MIN) default(shared) private(i, k)
    do j = 1, mg%ny(1)
      do i = 1, mg%nx(1)
        k = at(mg, 1_ik, i, j)
        z(base + i + j*n1) = 0.0_wp
        if (mg%kind(k) == MG_ACTIVE) z(base + i + j*n1) = mg%x(k)
      end do
    end do
    !$omp end parallel do
  end subroutine mg_apply

  subroutine inverse_diagonal(mg, l)
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: k0, k1, k
    k0 = mg%off(l)
    k1 = at(mg, l, mg%nx(l) + 1, mg%ny(l) + 1)
    do k = k0, k1
      mg%di(k) = 0.0_wp
      if (mg%kind(k) == MG_ACTIVE .and. mg%ad(k) > 0.0_wp) mg%di(k) = 1.0_wp/mg%ad(k)
    end do
  end subroutine inverse_diagonal

  subroutine coarsen(mg, l)
    !! Kinds and operator of level l + 1 from level l (A_c = P0^T A P0 / 2).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: ci, cj, f, c, sf, nxc, nyc, k(4), a
    real(wp) :: d
    sf = mg%nx(l) + 2
    nxc = mg%nx(l + 1)
    nyc = mg%ny(l + 1)
    !$omp parallel do if (nxc*nyc > PAR_MIN/4) default(shared) private(ci, cj, f, c, k, d, a)
    do cj = 0, nyc + 1
      do ci = 0, nxc + 1
        c = at(mg, l + 1, ci, cj)
        mg%ad(c) = 0.0_wp
        mg%ae(c) = 0.0_wp
        mg%an(c) = 0.0_wp
        if (ci == 0 .or. cj == 0 .or. ci == nxc + 1 .or. cj == nyc + 1) then   ! the ring: as the fine ring
          mg%kind(c) = mg%kind(at(mg, l, min(max(2*ci - 1, 0_ik), mg%nx(l) + 1), min(max(2*cj - 1, 0_ik), mg%ny(l) + 1)))
          cycle
        end if
        f = at(mg, l, 2*ci - 1, 2*cj - 1)
        k = [f, f + 1, f + sf, f + sf + 1]
        if (any(mg%kind(k) == MG_ACTIVE)) then
          mg%kind(c) = MG_ACTIVE
          d = 0.0_wp
          do a = 1, 4
            d = d + mg%ad(k(a))
          end do
          mg%ad(c) = 0.5_wp*d + (mg%ae(f) + mg%ae(f + sf)) + (mg%an(f) + mg%an(f + 1))
          mg%ae(c) = 0.5_wp*(mg%ae(f + 1) + mg%ae(f + sf + 1))
          mg%an(c) = 0.5_wp*(mg%an(f + sf) + mg%an(f + sf + 1))
        else if (any(mg%kind(k) == MG_DIRICHLET)) then
          mg%kind(c) = MG_DIRICHLET
        else
          mg%kind(c) = MG_NEUMANN
        end if
      end do
    end do
    !$omp end parallel do
    ! a coupling towards an inactive coarse cell is zero already: its children are inactive
  end subroutine coarsen

  subroutine weights(mg, l)
    !! wn of level l's active cells: 1 / (the sum of their prolongation weights from level l + 1,
    !! Neumann neighbours left out).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: i, j, f, ci, cj, di, dj
    real(wp) :: w
    !$omp parallel do if (mg%nx(l)*mg%ny(l) > PAR_MIN) default(shared) private(i, f, ci, cj, di, dj, w)
    do j = 1, mg%ny(l)
      do i = 1, mg%nx(l)
        f = at(mg, l, i, j)
        mg%wn(f) = 0.0_wp
        mg%t(f) = 0.0_wp   ! restrict reads wn t of every cell; the residual writes active rows' spans only
        if (mg%kind(f) /= MG_ACTIVE) cycle
        call parents(i, j, ci, cj, di, dj)
        w = 9.0_wp
        if (mg%kind(at(mg, l + 1, ci + di, cj)) /= MG_NEUMANN) w = w + 3.0_wp
        if (mg%kind(at(mg, l + 1, ci, cj + dj)) /= MG_NEUMANN) w = w + 3.0_wp
        if (mg%kind(at(mg, l + 1, ci + di, cj + dj)) /= MG_NEUMANN) w = w + 1.0_wp
        mg%wn(f) = 1.0_wp/w
      end do
    end do
    !$omp end parallel do
  end subroutine weights

  pure integer(ik) function lo_parity(i0, p)
    !! The first i >= i0 with i + p even: with p = j + colour, the first cell of row j whose
    !! colour mod(i + j, 2) is colour.
    integer(ik), intent(in) :: i0, p
    lo_parity = i0 + mod(i0 + p, 2_ik)
  end function lo_parity

  pure subroutine parents(i, j, ci, cj, di, dj)
    !! Parent (ci, cj) of fine cell (i, j) and the side (di, dj = -1 or 1) of its nearer neighbours.
    integer(ik), intent(in) :: i, j
    integer(ik), intent(out) :: ci, cj, di, dj
    ci = (i + 1)/2
    cj = (j + 1)/2
    di = merge(-1_ik, 1_ik, mod(i, 2_ik) == 1)
    dj = merge(-1_ik, 1_ik, mod(j, 2_ik) == 1)
  end subroutine parents

  subroutine mg_vcycle(mg)
    !! x = V b on level 1 (x from zero on every level): one symmetric V-cycle.
    type(mg_t), intent(inout) :: mg
    integer(ik) :: l, s
    do l = 1, mg%nlev - 1
      call zero_x(mg, l)
      do s = 1, NSMOOTH
        call sweep(mg, l, 0_ik)
        call sweep(mg, l, 1_ik)
      end do
      call residual(mg, l)
      call restrict(mg, l)
    end do
    l = mg%nlev
    call zero_x(mg, l)
    do s = 1, NCOARSE
      call sweep(mg, l, 0_ik)
      call sweep(mg, l, 1_ik)
      call sweep(mg, l, 1_ik)
      call sweep(mg, l, 0_ik)
    end do
    do l = mg%nlev - 1, 1, -1
      call prolong(mg, l)
      do s = 1, NSMOOTH
        call sweep(mg, l, 1_ik)
        call sweep(mg, l, 0_ik)
      end do
    end do
  end subroutine mg_vcycle

  subroutine zero_x(mg, l)
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    mg%x(mg%off(l):at(mg, l, mg%nx(l) + 1, mg%ny(l) + 1)) = 0.0_wp
  end subroutine zero_x

  subroutine sweep(mg, l, colour)
    !! One Gauss-Seidel half-sweep over the active cells of one colour (mod(i + j, 2) = colour).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l, colour
    integer(ik) :: i, j, c, s
    s = mg%nx(l) + 2
    !$omp parallel do if (mg%nx(l)*mg%ny(l) > PAR_MIN) default(shared) private(i, c)
    do j = 1, mg%ny(l)
      do i = lo_parity(mg%ilo(mg%roff(l) + j), j + colour), mg%ihi(mg%roff(l) + j), 2
        c = at(mg, l, i, j)
        mg%x(c) = mg%di(c)*(mg%b(c) - mg%ae(c)*mg%x(c + 1) - mg%ae(c - 1)*mg%x(c - 1) - mg%an(c)*mg%x(c + s) &
                            - mg%an(c - s)*mg%x(c - s))
      end do
    end do
    !$omp end parallel do
  end subroutine sweep

  subroutine residual(mg, l)
    !! t = b - A x on level l (0 on inactive cells).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: i, j, c, s
    s = mg%nx(l) + 2
    !$omp parallel do if (mg%nx(l)*mg%ny(l) > PAR_MIN) default(shared) private(i, c)
    do j = 1, mg%ny(l)
      do i = mg%ilo(mg%roff(l) + j), mg%ihi(mg%roff(l) + j)
        c = at(mg, l, i, j)
        if (mg%kind(c) /= MG_ACTIVE) then
          mg%t(c) = 0.0_wp
          cycle
        end if
        mg%t(c) = mg%b(c) - (mg%ad(c)*mg%x(c) + mg%ae(c)*mg%x(c + 1) + mg%ae(c - 1)*mg%x(c - 1) &
                             + mg%an(c)*mg%x(c + s) + mg%an(c - s)*mg%x(c - s))
      end do
    end do
    !$omp end parallel do
  end subroutine residual

  subroutine restrict(mg, l)
    !! b of level l + 1 = R t of level l, R = P^T: each coarse cell gathers the fine cells whose
    !! prolongation reads it (4 x 4 fine cells), with the same weights.
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: ci, cj, c, i, j
    real(wp) :: s, wy
    !$omp parallel do if (mg%nx(l)*mg%ny(l) > PAR_MIN) default(shared) private(ci, c, i, j, s, wy)
    do cj = 1, mg%ny(l + 1)
      do ci = mg%ilo(mg%roff(l + 1) + cj), mg%ihi(mg%roff(l + 1) + cj)
        c = at(mg, l + 1, ci, cj)
        mg%b(c) = 0.0_wp
        if (mg%kind(c) /= MG_ACTIVE) cycle
        s = 0.0_wp
        do j = max(2*cj - 2, 1_ik), min(2*cj + 1, mg%ny(l))
          wy = merge(3.0_wp, 1.0_wp, j == 2*cj - 1 .or. j == 2*cj)
          do i = max(2*ci - 2, 1_ik), min(2*ci + 1, mg%nx(l))
            s = s + (merge(3.0_wp, 1.0_wp, i == 2*ci - 1 .or. i == 2*ci)*wy)*mg%wn(at(mg, l, i, j))*mg%t(at(mg, l, i, j))
          end do
        end do
        mg%b(c) = s
      end do
    end do
    !$omp end parallel do
  end subroutine restrict

  subroutine prolong(mg, l)
    !! x of level l += P x of level l + 1 (bilinear; inactive coarse cells hold x = 0).
    type(mg_t), intent(inout) :: mg
    integer(ik), intent(in) :: l
    integer(ik) :: i, j, f, ci, cj, di, dj
    real(wp) :: s
    !$omp parallel do if (mg%nx(l)*mg%ny(l) > PAR_MIN) default(shared) private(i, f, ci, cj, di, dj, s)
    do j = 1, mg%ny(l)
      do i = mg%ilo(mg%roff(l) + j), mg%ihi(mg%roff(l) + j)
        f = at(mg, l, i, j)
        if (mg%kind(f) /= MG_ACTIVE) cycle
        call parents(i, j, ci, cj, di, dj)
        s = (9.0_wp*mg%wn(f))*mg%x(at(mg, l + 1, ci, cj)) + (3.0_wp*mg%wn(f))*mg%x(at(mg, l + 1, ci + di, cj)) &
            + (3.0_wp*mg%wn(f))*mg%x(at(mg, l + 1, ci, cj + dj)) + (1.0_wp*mg%wn(f))*mg%x(at(mg, l + 1, ci + di, cj + dj))
        mg%x(f) = mg%x(f) + s
      end do
    end do
    !$omp end parallel do
  end subroutine prolong
end module cpdi_multigrid
