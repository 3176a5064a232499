!> Kind parameters shared by every module of the solver.
module cpdi_kinds
  !! One place for the working precision (`wp`, equal to C double so the f2py layer
  !! and the core agree bit for bit) and the integer kind used at the API (`ik`).
  use, intrinsic :: iso_c_binding, only: c_double, c_int
  implicit none
  private

  integer, parameter, public :: wp = c_double   !! working real kind
  integer, parameter, public :: ik = c_int      !! integer kind of the API and of indices
end module cpdi_kinds
