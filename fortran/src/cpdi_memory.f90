!> Large pages for the large per-particle arrays.
module cpdi_memory
  !! A step streams every per-particle array (state, interpolation slots, projection
  !! cells) a few times. At 100k particles and more these arrays outgrow the caches, and
  !! with 4 KiB pages the address translations of a dozen concurrent streams miss the TLB
  !! as well. Linux backs memory with 2 MiB transparent huge pages where asked to
  !! (madvise MADV_HUGEPAGE; the system default here is "madvise"). `advise_huge` asks it
  !! for the 2 MiB-aligned interior of a freshly allocated array, before the array is
  !! first touched. It is advice: if the kernel declines (or has no transparent huge
  !! pages) the array keeps 4 KiB pages and nothing else changes. The memory used does not
  !! change either: only whole aligned 2 MiB blocks inside the array are advised.
  !! The gain, and that of glibc's `glibc.malloc.hugetlb=1` tunable (which advises every
  !! malloc'd block but must be set before the process starts), are measured in
  !! docs/notes/performance_measurements.md, "Transparent huge pages".
  use, intrinsic :: iso_c_binding, only: c_ptr, c_loc, c_int, c_size_t, c_intptr_t
  use cpdi_kinds, only: wp, ik
  implicit none
  private

  integer(c_int), parameter :: MADV_HUGEPAGE = 14_c_int        !! <sys/mman.h>, Linux
  integer(c_intptr_t), parameter :: HUGE_PAGE = 2097152_c_intptr_t !! 2 MiB

  interface
    function c_madvise(addr, length, advice) bind(C, name='madvise') result(rc)
      !! POSIX madvise(2).
      import :: c_ptr, c_size_t, c_int
      type(c_ptr), value :: addr
      integer(c_size_t), value :: length
      integer(c_int), value :: advice
      integer(c_int) :: rc
    end function c_madvise
  end interface

  public :: advise_huge, advise_huge_int

contains

  subroutine advise_huge(a, n)
    !! Advise huge pages for the n reals of a (any rank: specific procedures, so that an
    !! array of any rank passes by sequence association).
    integer(ik), intent(in) :: n
    real(wp), intent(inout), target :: a(*)
    if (n > 0) call advise_range(c_loc(a(1)), int(n, c_size_t)*int(storage_size(a(1))/8, c_size_t))
  end subroutine advise_huge

  subroutine advise_huge_int(a, n)
    !! Advise huge pages for the n integers of a.
    integer(ik), intent(in) :: n
    integer(ik), intent(inout), target :: a(*)
    if (n > 0) call advise_range(c_loc(a(1)), int(n, c_size_t)*int(storage_size(a(1))/8, c_size_t))
  end subroutine advise_huge_int

  subroutine advise_range(addr, nbytes)
    !! MADV_HUGEPAGE on the whole 2 MiB blocks inside [addr, addr + nbytes); best effort.
    type(c_ptr), intent(in) :: addr
    integer(c_size_t), intent(in) :: nbytes
    integer(c_intptr_t) :: a0, a1
    integer(c_int) :: rc
    a0 = transfer(addr, a0)
    a1 = (a0 + int(nbytes, c_intptr_t))/HUGE_PAGE*HUGE_PAGE
    a0 = (a0 + HUGE_PAGE - 1)/HUGE_PAGE*HUGE_PAGE
    if (a1 > a0) rc = c_madvise(transfer(a0, addr), int(a1 - a0, c_size_t), MADV_HUGEPAGE)
  end subroutine advise_range
end module cpdi_memory
