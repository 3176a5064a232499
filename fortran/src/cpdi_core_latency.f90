!> How long a cache line takes to travel between the cores of two OpenMP threads.
module cpdi_core_latency
  !! A benchmark control, not part of a step. Every step's scatters and the next step's
  !! shape phase move cache lines between the cores of the team; on a shared VM the host
  !! sometimes places two vCPUs where that round trip costs several times more, and the
  !! 2-thread speed-up then drops while busy-loop controls still show two full cores
  !! (measurements: docs/notes/threads.md). `core_round_trip` measures
  !! that cost directly: two threads bounce one shared integer `iters` times (thread 0
  !! writes an odd value and waits for the next even one, thread 1 answers), and the result
  !! is the wall time of one round trip. make bench counts a speed-up window only where the
  !! round trip is near the best the machine showed.
  use, intrinsic :: iso_fortran_env, only: int64
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT, CPDI_ERR_STATE
  !$ use omp_lib, only: omp_get_num_threads, omp_get_thread_num, omp_get_wtime
  implicit none
  private

  real(wp), parameter, public :: ROUND_TRIP_TIMEOUT = 5.0_wp   !! seconds before a partner counts as lost

  public :: core_round_trip

contains

  subroutine core_round_trip(iters, ns, st)
    !! Mean wall time of one round trip of a cache line between two threads [ns], over iters
    !! round trips. Needs an OpenMP build that may start 2 threads (its own num_threads(2),
    !! whatever OMP_NUM_THREADS says; not under OMP_THREAD_LIMIT=1); a thread that does not answer within ROUND_TRIP_TIMEOUT seconds ends the measurement with an error.
    integer(ik), intent(in) :: iters
    real(wp), intent(out) :: ns
    type(status_t), intent(inout) :: st
    integer(int64) :: flag
    integer :: nt
    real(wp) :: t0, t1
    logical :: lost
    ns = 0.0_wp
    if (iters < 1) then
      call st%set(CPDI_ERR_INPUT, 'the round-trip probe needs iters >= 1')
      return
    end if
    nt = 1
    flag = 0
    lost = .false.
    t0 = 0.0_wp
    t1 = 0.0_wp
    !$omp parallel num_threads(2) default(none) shared(flag, nt, t0, t1, lost, iters)
    !$ call bounce(flag, nt, t0, t1, lost, iters)
    !$omp end parallel
    if (nt < 2) then
      call st%set(CPDI_ERR_STATE, 'the round-trip probe needs 2 OpenMP threads; build with OpenMP '// &
                  'and do not set OMP_THREAD_LIMIT=1 in the probing process')
    else if (lost) then
      call st%set(CPDI_ERR_STATE, 'the round-trip probe lost its partner thread for 5 s; the machine '// &
                  'is overloaded, probe again when it is idle')
    else
      ns = (t1 - t0)/real(iters, wp)*1.0e9_wp
    end if
  end subroutine core_round_trip

  subroutine bounce(flag, nt, t0, t1, lost, iters)
    !! Body of core_round_trip's parallel region: threads 0 and 1 bounce flag, others idle.
    integer(int64), intent(inout) :: flag
    integer, intent(inout) :: nt
    real(wp), intent(inout) :: t0, t1
    logical, intent(inout) :: lost
    integer(ik), intent(in) :: iters
    integer(int64) :: i, want, v
    integer :: me
    logical :: gone
    me = 0
    !$ me = omp_get_thread_num()
    !$omp single
    !$ nt = omp_get_num_threads()
    !$omp end single
    if (nt < 2 .or. me > 1) return
    !$omp master
    !$ t0 = omp_get_wtime()
    !$omp end master
    gone = .false.
    do i = 1, int(iters, int64)
      if (me == 0) then
        !$omp atomic write seq_cst
        flag = 2*i - 1
        want = 2*i
      else
        want = 2*i - 1
      end if
      call await(flag, want, v, gone)
      if (gone) exit
      if (me == 1) then
        !$omp atomic write seq_cst
        flag = 2*i
      end if
    end do
    if (gone) then
      !$omp atomic write
      lost = .true.
      ! release a partner that waits for this thread's next write
      !$omp atomic write seq_cst
      flag = -1
    end if
    !$omp master
    !$ t1 = omp_get_wtime()
    !$omp end master
  end subroutine bounce

  subroutine await(flag, want, v, gone)
    !! Spin until flag holds want; gone when the partner gave up (-1) or took too long.
    integer(int64), intent(inout) :: flag
    integer(int64), intent(in) :: want
    integer(int64), intent(out) :: v
    logical, intent(out) :: gone
    integer(int64) :: spins
    real(wp) :: since
    gone = .false.
    since = -1.0_wp
    spins = 0
    do
      !$omp atomic read seq_cst
      v = flag
      if (v == want) return
      if (v == -1) exit
      spins = spins + 1
      if (iand(spins, 65535_int64) == 0) then   ! look at the clock now and then, not every spin
        !$ if (since < 0.0_wp) since = omp_get_wtime()
        !$ if (omp_get_wtime() - since > ROUND_TRIP_TIMEOUT) exit
      end if
    end do
    gone = .true.
  end subroutine await
end module cpdi_core_latency
