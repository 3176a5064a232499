!> The bench's probe of the host: the extension _cpdi_bench (cpdi_bench.pyf), which tools/bench.py
!> loads from the checkout; built with the core but never installed (docs/design.md).
module cpdi_bench_probe
  !! What moving data between the cores costs now (cpdi_core_latency), with the conventions of
  !! cpdi_api: ierr and a message, no stop.
  use, intrinsic :: iso_c_binding, only: c_double, c_int
  use cpdi_kinds, only: ik
  use cpdi_status, only: status_t, MSG_LEN, finish => status_finish
  implicit none
  private

  public :: cpdi_core_round_trip

contains

  subroutine cpdi_core_round_trip(iters, ns, ierr, msg)
    !! Mean wall time [ns] of one cache-line round trip between two OpenMP threads, over
    !! iters round trips (a control of make bench; cpdi_core_latency). Runs on 2 threads.
    use cpdi_core_latency, only: core_round_trip
    integer(c_int), intent(in) :: iters
    real(c_double), intent(out) :: ns
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    type(status_t) :: st
    call core_round_trip(int(iters, ik), ns, st)
    call finish(st, ierr, msg)
  end subroutine cpdi_core_round_trip

end module cpdi_bench_probe
