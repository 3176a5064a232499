!> Error codes and the status object every fallible routine fills in.
module cpdi_status
  !! Errors follow json-fortran/fpm practice: a status object carries a code and a
  !! message, and nothing in the solver ever stops the process.
  use, intrinsic :: iso_c_binding, only: c_int
  use cpdi_kinds, only: ik
  implicit none
  private

  integer(ik), parameter, public :: CPDI_OK = 0            !! success
  integer(ik), parameter, public :: CPDI_ERR_INPUT = 1     !! bad argument or parameter
  integer(ik), parameter, public :: CPDI_ERR_STATE = 2     !! call out of order (e.g. no grid yet)
  integer(ik), parameter, public :: CPDI_ERR_NAN = 3       !! NaN or Inf appeared during a step
  integer(ik), parameter, public :: CPDI_ERR_OUTSIDE = 4   !! particle or domain corner left the grid
  integer(ik), parameter, public :: CPDI_ERR_JACOBIAN = 5  !! det F <= 0
  integer(ik), parameter, public :: CPDI_ERR_DOMAIN = 6    !! CPDI domain inverted
  integer(ik), parameter, public :: CPDI_ERR_CFL = 7       !! fixed time step above the stable limit
  integer(ik), parameter, public :: CPDI_ERR_LAPACK = 8    !! LAPACK reported failure
  integer(ik), parameter, public :: CPDI_ERR_HANDLE = 9    !! unknown simulation handle
  integer(ik), parameter, public :: CPDI_ERR_ALLOC = 10    !! allocation failed
  integer(ik), parameter, public :: CPDI_ERR_SOLVE = 11    !! pressure solve did not converge

  integer, parameter, public :: MSG_LEN = 512              !! length of every message

  public :: status_finish

  type, public :: status_t
    !! Result of a fallible operation.
    integer(ik) :: code = CPDI_OK          !! one of the CPDI_* codes
    character(len=MSG_LEN) :: msg = ''     !! human-readable cause and fix
  contains
    procedure :: set => status_set
    procedure :: ok => status_ok
    procedure :: clear => status_clear
  end type status_t

contains

  pure subroutine status_set(self, code, msg)
    !! Record an error. The first error wins: later ones do not overwrite it.
    class(status_t), intent(inout) :: self
    integer(ik), intent(in) :: code
    character(len=*), intent(in) :: msg
    if (self%code /= CPDI_OK) return
    self%code = code
    self%msg = msg
  end subroutine status_set

  pure logical function status_ok(self)
    !! True when no error has been recorded.
    class(status_t), intent(in) :: self
    status_ok = self%code == CPDI_OK
  end function status_ok

  pure subroutine status_finish(st, ierr, msg)
    !! An API routine's outputs from its status: the code as ierr and the message (every extension's
    !! routines end with it: cpdi_api, the test hooks, the bench probe).
    type(status_t), intent(in) :: st
    integer(c_int), intent(out) :: ierr
    character(len=MSG_LEN), intent(out) :: msg
    ierr = int(st%code, c_int)
    msg = st%msg
  end subroutine status_finish

  pure subroutine status_clear(self)
    !! Reset to success.
    class(status_t), intent(inout) :: self
    self%code = CPDI_OK
    self%msg = ''
  end subroutine status_clear
end module cpdi_status
