!> Particle state stored as a structure of arrays.
module cpdi_particles
  !! Two-component quantities are stored `(2, n)` and 2x2 tensors `(4, n)` so a
  !! particle's data sit together while each field stays one contiguous array.
  !! Tensor layout (column-major 2x2): `[A11, A21, A12, A22]`.
  !! Stress layout: `[sxx, syy, sxy, szz]` (Cauchy, plane strain).
  !! Domain layout: `[r1x, r1y, r2x, r2y]` (CPDI half-vectors).
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  use cpdi_memory, only: advise_huge
  implicit none
  private

  type, public :: particles_t
    integer(ik) :: n = 0                    !! number of particles
    real(wp), allocatable :: x(:, :)        !! position [m] (2, n)
    real(wp), allocatable :: v(:, :)        !! velocity [m/s] (2, n)
    real(wp), allocatable :: m(:)           !! mass [kg per m thickness]
    real(wp), allocatable :: vol0(:)        !! initial volume (area) [m^2]
    real(wp), allocatable :: vol(:)         !! current volume J*vol0 [m^2]
    real(wp), allocatable :: F(:, :)        !! total deformation gradient (4, n)
    real(wp), allocatable :: L(:, :)        !! velocity gradient of the last step (4, n)
    real(wp), allocatable :: sig(:, :)      !! Cauchy stress [Pa] (4, n)
    real(wp), allocatable :: r0(:, :)       !! initial CPDI domain vectors (4, n)
    real(wp), allocatable :: r(:, :)        !! current CPDI interpolation domain vectors (4, n)
    real(wp), allocatable :: bf(:, :)       !! external body force per unit mass [m/s^2] (2, n)
    real(wp), allocatable :: aw(:, :)       !! the water's force per unit mass on a free rigid body in its
                                            !! last step [m/s^2] (2, n): what the walls hold (cpdi_rigid_body)
    real(wp), allocatable :: psi(:)         !! stored strain energy [J per m thickness]
    real(wp), allocatable :: jbar(:)        !! projected Jacobian (equals det F without projection)
    real(wp), allocatable :: work(:, :)     !! per-particle scratch (3, n) for the projection
    integer(ik), allocatable :: mat(:)      !! material index, 1-based
  end type particles_t

  public :: particles_alloc

contains

  subroutine particles_alloc(p, n, st)
    !! (Re)allocate storage for n particles and set the neutral state.
    type(particles_t), intent(inout) :: p
    integer(ik), intent(in) :: n
    type(status_t), intent(inout) :: st
    integer :: ierr
    if (allocated(p%x)) deallocate (p%x, p%v, p%m, p%vol0, p%vol, p%F, p%L, p%sig, p%r0, p%r, &
                                    p%bf, p%aw, p%psi, p%jbar, p%work, p%mat)
    allocate (p%x(2, n), p%v(2, n), p%m(n), p%vol0(n), p%vol(n), p%F(4, n), p%L(4, n), p%sig(4, n), &
              p%r0(4, n), p%r(4, n), p%bf(2, n), p%aw(2, n), p%psi(n), p%jbar(n), p%work(3, n), p%mat(n), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate particle storage; use fewer particles')
      p%n = 0
      return
    end if
    p%n = n
    call advise_huge(p%x, size(p%x))   ! before the first touch (cpdi_memory)
    call advise_huge(p%v, size(p%v))
    call advise_huge(p%F, size(p%F))
    call advise_huge(p%L, size(p%L))
    call advise_huge(p%sig, size(p%sig))
    call advise_huge(p%r0, size(p%r0))
    call advise_huge(p%r, size(p%r))
    call advise_huge(p%bf, size(p%bf))
    call advise_huge(p%work, size(p%work))
    p%F(1, :) = 1.0_wp
    p%F(2, :) = 0.0_wp
    p%F(3, :) = 0.0_wp
    p%F(4, :) = 1.0_wp
    p%L = 0.0_wp
    p%sig = 0.0_wp
    p%bf = 0.0_wp
    p%aw = 0.0_wp
    p%psi = 0.0_wp
    p%jbar = 1.0_wp
  end subroutine particles_alloc
end module cpdi_particles
