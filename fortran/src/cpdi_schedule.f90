!> Work division for OpenMP that gives the same bits at any thread count.
module cpdi_schedule
  !! Two devices make every parallel loop of a step independent of the number of threads:
  !!
  !! * **Chunks** (gathers and reductions). Particles are cut into `NCHUNK` fixed blocks
  !!   of consecutive indices, whatever the thread count. A reduction (energy, momentum)
  !!   sums each block in index order into its own slot, and the slots are then added in
  !!   block order, serially. The error scan takes the lowest failing particle. A block's
  !!   work and sums do not depend on which thread runs it, so blocks are handed out by
  !!   `block_start` / `block_next` (affine with stealing): thread t of nt owns the blocks
  !!   t NCHUNK/nt + 1 .. (t + 1) NCHUNK/nt and runs them in order, and a thread that has
  !!   finished its own takes the remaining blocks of the others from their far end. Each
  !!   block is claimed once, by an atomic swap of its ticket (64 per loop, not per particle).
  !!   Owning keeps a block's particle data in the same core's cache from phase to phase
  !!   (faster than `schedule(dynamic, 1)`, which hands blocks to whichever thread comes
  !!   first); stealing keeps what dynamic gave: a thread on a slowed core (a vCPU shared
  !!   with other work) does fewer blocks instead of holding the other at every barrier, as a
  !!   plain static schedule would (measurements: docs/notes/threads.md).
  !! * **Strips** (scatters to the grid). Particles are binned by the lowest node row of
  !!   their stencil into horizontal strips `width` node rows high, with width at least
  !!   the tallest stencil's span (last minus first row). Two strips of the same parity then touch disjoint nodes,
  !!   so all even strips are scattered in parallel, then all odd strips (graph colouring
  !!   in two colours). Every node receives the contributions of at most one even and one
  !!   odd strip, each in particle-index order: the sums are bitwise the same at any
  !!   thread count, with no atomics and no per-thread grid copies. The strips of a colour
  !!   are handed out like blocks (`strip_start` / `block_next`): thread t owns the strips
  !!   that begin in the t-th of nt equal parts of the strip-ordered particles, so with
  !!   particles numbered row by row a thread scatters mostly the particles whose blocks it
  !!   owns, and their shape functions stay in its core's cache. With `schedule(dynamic, 1)`
  !!   about half of them were read by the other core every step, and its next shape phase
  !!   had to take those cache lines back: the 2-thread step lost its speed-up whenever the
  !!   host put the two cores far apart (docs/notes/threads.md).
  !!
  !! The binning is a stable counting sort, O(n), with storage sized once. Horizontal
  !! strips keep particles seeded row by row (and nodes, numbered row by row) contiguous in
  !! memory within a strip; vertical strips lose that locality (docs/notes/threads.md).
  use, intrinsic :: iso_fortran_env, only: int64
  use cpdi_kinds, only: ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  !$ use omp_lib, only: omp_get_num_threads, omp_get_thread_num
  implicit none
  private

  integer(ik), parameter, public :: NCHUNK = 64   !! fixed particle blocks of a reduction
  integer, parameter, public :: MAX_THREADS = 256  !! most threads a step runs on (block tickets)

  ! Block hand-out state (block_start, strip_start, block_next). Module storage: the
  ! extension is not thread-safe from Python (it holds the GIL), so one step runs at a time
  ! in a process. claim(i): ticket of the loop that took item i (a block, or the i-th strip
  ! of a colour); sized by claims_reserve, serially. ticket(1, t): thread t's ticket of its
  ! current loop (one cache line per thread). Every thread of a region meets the same
  ! sequence of block loops, so their tickets agree once blocks_region and blocks_enter
  ! have set them to the same value at the start of the region.
  integer(int64), allocatable, save :: claim(:)
  integer(int64), save :: ticket(8, 0:MAX_THREADS - 1) = 0
  integer(int64), save :: gen = 0

  type, public :: blocks_t
    !! One thread's iterator over the items of one loop (a local of the loop's routine,
    !! hence private to the thread): the NCHUNK blocks, or the strips of one colour. Item i
    !! is block i, or strip first + 2 (i - 1).
    integer :: nt, tid, victim
    integer(ik) :: pos, hi
    logical :: stealing
    integer(int64) :: tk
    integer(ik) :: first, stride
    integer(ik) :: cut(0:MAX_THREADS)   !! thread t owns items cut(t) + 1 .. cut(t + 1) (set for t <= nt)
  end type blocks_t

  type, public :: strips_t
    integer(ik) :: nstrip = 0                !! strips in use
    integer(ik) :: width = 0                 !! node rows per strip
    integer(ik) :: rlo = 0                   !! lowest row of any particle (0-based)
    integer(ik) :: rhi = -1                  !! highest row of any particle (0-based)
    integer(ik), allocatable :: perm(:)      !! particles ordered strip by strip (n)
    integer(ik), allocatable :: start(:)     !! first position of each strip in perm (nrow + 2)
    integer(ik), allocatable :: next(:, :)   !! per strip and block: count, then fill pointer (nrow + 1, NCHUNK)
    integer(ik) :: cb(3, NCHUNK) = 0         !! per block: highest strip, lowest row, highest row
  end type strips_t

  public :: strips_alloc, strips_build, chunk_range, blocks_region, blocks_enter, block_start, strip_start, block_next

contains

  subroutine blocks_region()
    !! Before a parallel region that runs block loops (serial code): a ticket above every
    !! ticket used so far, for blocks_enter.
    call claims_reserve(NCHUNK)
    gen = maxval(ticket(1, :)) + 1
  end subroutine blocks_region

  subroutine claims_reserve(n)
    !! Room for n items in one loop (serial code; grows, never shrinks).
    integer(ik), intent(in) :: n
    if (allocated(claim)) then
      if (size(claim, kind=ik) >= n) return
      deallocate (claim)
    end if
    allocate (claim(max(n, NCHUNK)))
    claim = 0
  end subroutine claims_reserve

  subroutine blocks_enter()
    !! First thing in such a region, on every thread: all threads start from the same ticket.
    integer :: t
    t = 0
    !$ t = omp_get_thread_num()
    if (t < MAX_THREADS) ticket(1, t) = gen
  end subroutine blocks_enter

  subroutine block_start(it)
    !! Start a loop over the NCHUNK blocks (every thread of the team calls it; the loop
    !! ends with an `!$omp barrier`, where `!$omp end do` would put it):
    !!   call block_start(blk); do while (block_next(blk, c)); ...; end do; !$omp barrier
    !! Serially (outside a parallel region, or a team of one) the blocks run 1..NCHUNK.
    type(blocks_t), intent(out) :: it
    integer :: t
    call iter_begin(it)
    do t = 0, it%nt
      it%cut(t) = int(int(t, int64)*NCHUNK/it%nt, ik)
    end do
    call iter_own(it)
  end subroutine block_start

  subroutine strip_start(it, sp, colour)
    !! Start a loop over the strips colour, colour + 2, ... of sp (colour 1 or 2), used as
    !! block_start is: block_next then gives strip numbers. Thread t owns the strips whose
    !! first particle lies in the t-th of nt equal parts of sp%perm (contiguous in the
    !! strip order, so the threads' ranges follow each other as blocks do). Serially the
    !! strips run in increasing order.
    type(blocks_t), intent(out) :: it
    type(strips_t), intent(in) :: sp
    integer(ik), intent(in) :: colour
    integer(ik) :: ni, ntot, lo, hi, mid
    integer :: t
    call iter_begin(it)
    it%first = colour
    it%stride = 2
    ni = 0
    if (sp%nstrip >= colour) ni = (sp%nstrip - colour)/2 + 1
    ntot = 0
    if (sp%nstrip > 0) ntot = sp%start(sp%nstrip + 1) - 1
    it%cut(0) = 0
    it%cut(it%nt) = ni
    do t = 1, it%nt - 1   ! items whose first particle lies before t ntot / nt
      lo = 0
      hi = ni
      do while (lo < hi)
        mid = (lo + hi + 1)/2
        if (int(sp%start(colour + 2*(mid - 1)) - 1, int64)*it%nt < int(t, int64)*ntot) then
          lo = mid
        else
          hi = mid - 1
        end if
      end do
      it%cut(t) = lo
    end do
    call iter_own(it)
  end subroutine strip_start

  subroutine iter_begin(it)
    !! The team, this thread, not yet stealing, items 1, 2, ... (no default initialisation
    !! in blocks_t: an iterator is a local of every loop, and cut need not be copied in).
    type(blocks_t), intent(out) :: it
    it%nt = 1
    it%tid = 0
    !$ it%nt = omp_get_num_threads()
    !$ it%tid = omp_get_thread_num()
    it%stealing = .false.
    it%victim = it%tid
    it%tk = 0
    it%first = 1
    it%stride = 1
  end subroutine iter_begin

  subroutine iter_own(it)
    !! This loop's ticket and this thread's own range (a team of one runs every item).
    type(blocks_t), intent(inout) :: it
    if (it%nt == 1) then
      it%pos = 0
      it%hi = it%cut(1)
      return
    end if
    ticket(1, it%tid) = ticket(1, it%tid) + 1
    it%tk = ticket(1, it%tid)
    it%pos = it%cut(it%tid)
    it%hi = it%cut(it%tid + 1)
  end subroutine iter_own

  logical function block_next(it, c)
    !! The next block (or strip) c for this thread: its own items in increasing order, then
    !! the items still left in the other threads' ranges, each from its far end down to
    !! where its owner got to. .false. when no item is left.
    type(blocks_t), intent(inout) :: it
    integer(ik), intent(out) :: c
    block_next = .false.
    c = 0
    if (it%nt == 1) then
      it%pos = it%pos + 1
      c = it%first + it%stride*(it%pos - 1)
      block_next = it%pos <= it%hi
      return
    end if
    if (.not. it%stealing) then
      it%pos = it%pos + 1
      if (it%pos <= it%hi) then
        if (take(it%pos, it%tk)) then
          c = it%first + it%stride*(it%pos - 1)
          block_next = .true.
          return
        end if
      end if
      it%stealing = .true.   ! own range done, or its rest taken by another thread
      it%pos = 0
    end if
    do
      if (it%pos <= it%cut(it%victim)) then   ! the next thread's range, from its far end
        it%victim = mod(it%victim + 1, it%nt)
        if (it%victim == it%tid) return
        it%pos = it%cut(it%victim + 1)
        cycle
      end if
      if (take(it%pos, it%tk)) then
        c = it%first + it%stride*(it%pos - 1)
        it%pos = it%pos - 1
        block_next = .true.
        return
      end if
      it%pos = 0   ! met the owner (or another thief): the rest of this range is taken
    end do
  end function block_next

  logical function take(c, tk)
    !! Claim block c for the loop with ticket tk; .false. if it already has it.
    integer(ik), intent(in) :: c
    integer(int64), intent(in) :: tk
    integer(int64) :: old
    !$omp atomic capture
    old = claim(c)
    claim(c) = tk
    !$omp end atomic
    take = old /= tk
  end function take

  pure subroutine chunk_range(c, n, lo, hi)
    !! Particles lo..hi of block c (1..NCHUNK) of n; empty (hi < lo) for small n.
    integer(ik), intent(in) :: c, n
    integer(ik), intent(out) :: lo, hi
    lo = int(int(c - 1, int64)*int(n, int64)/NCHUNK, ik) + 1
    hi = int(int(c, int64)*int(n, int64)/NCHUNK, ik)
  end subroutine chunk_range

  subroutine strips_alloc(sp, n, nrow, st)
    !! Storage for n particles on a grid of nrow node rows.
    type(strips_t), intent(inout) :: sp
    integer(ik), intent(in) :: n, nrow
    type(status_t), intent(inout) :: st
    integer :: ierr
    if (allocated(sp%perm)) deallocate (sp%perm, sp%start, sp%next)
    allocate (sp%perm(n), sp%start(nrow + 2), sp%next(nrow + 1, NCHUNK), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the particle ordering; use fewer particles')
      return
    end if
    call claims_reserve(nrow/2 + 1)   ! strips of one colour
  end subroutine strips_alloc

  subroutine strips_build(sp, row, span)
    !! Bin the particles by row(ip) (lowest node row of the stencil, 0-based) into strips
    !! span rows high (span: tallest stencil, last minus first node row). A strip b then
    !! reaches rows below (b + 1) span + span, short of strip b + 2: same-colour strips
    !! touch disjoint nodes. Also records the lowest and highest row (rlo, rhi).
    !! A stable counting sort over the fixed particle blocks (OpenMP): each block counts
    !! its particles per strip, the offsets follow strip by strip and, within a strip,
    !! block by block, and each block fills its positions in index order. perm is the one
    !! of a serial stable sort, at any thread count.
    !! Orphaned worksharing: called by every thread of the step's parallel region (or
    !! serially outside one); the per-block maxima and minima are reduced in a single.
    type(strips_t), intent(inout) :: sp
    integer(ik), intent(in) :: row(:)
    integer(ik), intent(in) :: span
    integer(ik) :: b, c, lo, hi, ncap, pos, cnt, width
    type(blocks_t) :: blk
    ncap = size(sp%start) - 1
    width = max(span, 1)
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, size(row, kind=ik), lo, hi)
      sp%cb(:, c) = [0_ik, huge(1_ik), -1_ik]
      call count_block(lo, hi, row, width, ncap, sp%next(:, c), sp%cb(1, c), sp%cb(2, c), sp%cb(3, c))
    end do
    !$omp barrier
    !$omp single
    sp%width = width
    sp%nstrip = maxval(sp%cb(1, :))
    sp%rlo = minval(sp%cb(2, :))
    sp%rhi = maxval(sp%cb(3, :))
    pos = 1
    do b = 1, sp%nstrip
      sp%start(b) = pos
      do c = 1, NCHUNK
        cnt = sp%next(b, c)
        sp%next(b, c) = pos
        pos = pos + cnt
      end do
    end do
    sp%start(sp%nstrip + 1) = pos
    !$omp end single
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, size(row, kind=ik), lo, hi)
      call fill_block(lo, hi, row, width, ncap, sp%next(:, c), sp%perm)
    end do
    !$omp barrier
  end subroutine strips_build

  pure subroutine count_block(lo, hi, row, width, ncap, cnt, nstrip, rlo, rhi)
    !! Particles lo..hi per strip (cnt), and the running highest strip and row range.
    integer(ik), intent(in) :: lo, hi, row(*), width, ncap
    integer(ik), intent(out) :: cnt(ncap)
    integer(ik), intent(inout) :: nstrip, rlo, rhi
    integer(ik) :: ip, b
    cnt = 0
    do ip = lo, hi
      rlo = min(rlo, row(ip))
      rhi = max(rhi, row(ip))
      b = min(row(ip)/width + 1, ncap)
      cnt(b) = cnt(b) + 1
      nstrip = max(nstrip, b)
    end do
  end subroutine count_block

  pure subroutine fill_block(lo, hi, row, width, ncap, next, perm)
    !! Particles lo..hi into perm at their strips' fill pointers next, in index order.
    integer(ik), intent(in) :: lo, hi, row(*), width, ncap
    integer(ik), intent(inout) :: next(ncap), perm(*)
    integer(ik) :: ip, b
    do ip = lo, hi
      b = min(row(ip)/width + 1, ncap)
      perm(next(b)) = ip
      next(b) = next(b) + 1
    end do
  end subroutine fill_block
end module cpdi_schedule
