!> Constitutive models: Hencky hyperelasticity, compressible neo-Hookean,
!> weakly compressible Newtonian fluid and rigid.
module cpdi_materials
  !! Every model is a pure kernel from (F, L, J_vol) to Cauchy stress and stored energy.
  !! `jv` is the Jacobian used for the volumetric part: det F without projection, the
  !! projected value with it (Mast et al. 2012); the deviatoric part always comes from F.
  !! Plane strain: F33 = 1; the stress carries its out-of-plane component szz.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT
  use cpdi_kinematics, only: log_strain, left_cauchy_green, det2
  implicit none
  private

  integer(ik), parameter, public :: MAT_HENCKY = 1       !! tau = lam tr(e) I + 2 mu e, sigma = tau/J
  integer(ik), parameter, public :: MAT_FLUID = 2        !! p = -K ln J, plus 2 visc dev(D)
  integer(ik), parameter, public :: MAT_RIGID = 3        !! prescribed velocity, no stress
  integer(ik), parameter, public :: MAT_NEOHOOKEAN = 4   !! sigma = lam ln J / J I + mu/J (b - I)
  integer(ik), parameter, public :: MAT_RIGID_BODY = 5   !! a free rigid body (cpdi_rigid_body), no stress

  integer(ik), parameter, public :: KIN_LOG = 0          !! finite strain: Hencky log strain
  integer(ik), parameter, public :: KIN_SMALL = 1        !! small strain: eps = sym(F) - I

  integer, parameter, public :: NMATPROP = 8  !! props: density, E, nu, K, viscosity, vx, vy, project
  !! (rigid_body: props(2) is its Coulomb friction coefficient against the walls)

  type, public :: material_t
    integer(ik) :: model = MAT_HENCKY
    real(wp) :: rho0 = 0.0_wp     !! reference density [kg/m^3]
    real(wp) :: lam = 0.0_wp      !! Lame lambda [Pa] (solids)
    real(wp) :: mu = 0.0_wp       !! shear modulus [Pa] (solids)
    real(wp) :: K = 0.0_wp        !! bulk modulus [Pa]
    real(wp) :: visc = 0.0_wp     !! dynamic viscosity [Pa s] (fluid)
    real(wp) :: vel(2) = 0.0_wp   !! prescribed velocity [m/s] (rigid)
    real(wp) :: friction = 0.0_wp !! Coulomb coefficient against the walls (rigid_body)
    real(wp) :: pmod = 0.0_wp     !! P-wave modulus K + 4G/3 [Pa], for the signal speed
    logical :: project = .false.  !! takes part in the volumetric projection
  end type material_t

  public :: material_init, material_stress, material_stresses

contains

  subroutine material_init(mat, model, props, imat, st)
    !! Build and validate material number imat from its flat properties.
    type(material_t), intent(out) :: mat
    integer(ik), intent(in) :: model
    real(wp), intent(in) :: props(NMATPROP)
    integer(ik), intent(in) :: imat
    type(status_t), intent(inout) :: st
    real(wp) :: E, nu
    character(len=200) :: buf

    if (any(props /= props) .or. any(abs(props) > huge(1.0_wp))) then
      write (buf, '(a,i0,a)') 'material ', imat, ' has a NaN or infinite property; give finite SI values'
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    mat%model = model
    mat%rho0 = props(1)
    mat%project = props(8) /= 0.0_wp .and. model /= MAT_RIGID .and. model /= MAT_RIGID_BODY
    if (.not. (props(1) > 0.0_wp)) then
      write (buf, '(a,i0,a,es11.3,a)') 'material ', imat, ' density is ', props(1), &
        '; density must be positive (kg/m^3)'
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    select case (model)
    case (MAT_HENCKY, MAT_NEOHOOKEAN)
      E = props(2)
      nu = props(3)
      if (.not. (E > 0.0_wp)) then
        write (buf, '(a,i0,a,es11.3,a)') 'material ', imat, ' youngs_modulus is ', E, '; it must be positive (Pa)'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
      if (.not. (nu > -1.0_wp .and. nu < 0.5_wp)) then
        write (buf, '(a,i0,a,f8.4,a)') 'material ', imat, ' poisson_ratio is ', nu, &
          '; it must lie in (-1, 0.5)'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
      mat%mu = E/(2.0_wp*(1.0_wp + nu))
      mat%lam = E*nu/((1.0_wp + nu)*(1.0_wp - 2.0_wp*nu))
      mat%K = mat%lam + 2.0_wp*mat%mu/3.0_wp
      mat%pmod = mat%lam + 2.0_wp*mat%mu
    case (MAT_FLUID)
      mat%K = props(4)
      mat%visc = props(5)
      if (.not. (mat%K > 0.0_wp)) then
        write (buf, '(a,i0,a,es11.3,a)') 'material ', imat, ' bulk_modulus is ', mat%K, '; it must be positive (Pa)'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
      if (mat%visc < 0.0_wp) then
        write (buf, '(a,i0,a,es11.3,a)') 'material ', imat, ' viscosity is ', mat%visc, &
          '; it must be zero or positive (Pa s)'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
      mat%pmod = mat%K
    case (MAT_RIGID)
      mat%vel = props(6:7)
      mat%pmod = 0.0_wp
    case (MAT_RIGID_BODY)
      mat%friction = props(2)
      mat%pmod = 0.0_wp
      if (.not. (mat%friction >= 0.0_wp)) then
        write (buf, '(a,i0,a,es11.3,a)') 'material ', imat, ' friction is ', mat%friction, &
          '; the Coulomb coefficient must be zero or positive'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
    case default
      write (buf, '(a,i0,a,i0,a)') 'material ', imat, ' has model id ', model, &
        '; use 1 hencky, 2 newtonian_fluid, 3 rigid, 4 neo_hookean or 5 rigid_body'
      call st%set(CPDI_ERR_INPUT, trim(buf))
    end select
  end subroutine material_init

  pure subroutine material_stress(mat, kin, F, L, jv, sig, psi)
    !! Cauchy stress sig = [sxx, syy, sxy, szz] and stored energy per unit reference
    !! volume psi, for deformation gradient F, velocity gradient L and volumetric
    !! Jacobian jv (equal to det F when no projection acts).
    type(material_t), intent(in) :: mat
    integer(ik), intent(in) :: kin
    real(wp), intent(in) :: F(4), L(4), jv
    real(wp), intent(out) :: sig(4), psi
    real(wp) :: e(3), tr, lnj, j, shift, b(3), d11, d22, d12, trd, p

    select case (mat%model)
    case (MAT_HENCKY)
      if (kin == KIN_SMALL) then
        e = [F(1) - 1.0_wp, F(4) - 1.0_wp, 0.5_wp*(F(2) + F(3))]
        shift = (jv - det2(F))/3.0_wp
        e(1:2) = e(1:2) + shift
        tr = e(1) + e(2) + shift
        sig = [mat%lam*tr + 2.0_wp*mat%mu*e(1), mat%lam*tr + 2.0_wp*mat%mu*e(2), 2.0_wp*mat%mu*e(3), &
               mat%lam*tr + 2.0_wp*mat%mu*shift]
        psi = 0.5_wp*mat%lam*tr*tr + mat%mu*(e(1)**2 + e(2)**2 + 2.0_wp*e(3)**2 + shift**2)
      else
        call log_strain(F, e)
        j = jv
        lnj = log(jv)
        ! replace the volumetric log strain ln(det F)/3 I by ln(jv)/3 I
        shift = (lnj - log(det2(F)))/3.0_wp
        e(1:2) = e(1:2) + shift
        tr = lnj
        sig = [mat%lam*tr + 2.0_wp*mat%mu*e(1), mat%lam*tr + 2.0_wp*mat%mu*e(2), 2.0_wp*mat%mu*e(3), &
               mat%lam*tr + 2.0_wp*mat%mu*shift]/j
        psi = 0.5_wp*mat%lam*tr*tr + mat%mu*(e(1)**2 + e(2)**2 + 2.0_wp*e(3)**2 + shift**2)
      end if
    case (MAT_NEOHOOKEAN)
      call left_cauchy_green(F, b)
      j = det2(F)
      lnj = log(jv)
      sig(1) = mat%lam*lnj/jv + mat%mu/j*(b(1) - 1.0_wp)
      sig(2) = mat%lam*lnj/jv + mat%mu/j*(b(2) - 1.0_wp)
      sig(3) = mat%mu/j*b(3)
      sig(4) = mat%lam*lnj/jv
      psi = 0.5_wp*mat%mu*(b(1) + b(2) - 2.0_wp) - mat%mu*log(j) + 0.5_wp*mat%lam*lnj*lnj
    case (MAT_FLUID)
      if (kin == KIN_SMALL) then
        lnj = jv - 1.0_wp
      else
        lnj = log(jv)
      end if
      p = -mat%K*lnj
      d11 = L(1)
      d22 = L(4)
      d12 = 0.5_wp*(L(2) + L(3))
      trd = (d11 + d22)/3.0_wp
      sig = [-p + 2.0_wp*mat%visc*(d11 - trd), -p + 2.0_wp*mat%visc*(d22 - trd), 2.0_wp*mat%visc*d12, &
             -p - 2.0_wp*mat%visc*trd]
      psi = 0.5_wp*mat%K*lnj*lnj
    case default
      sig = 0.0_wp
      psi = 0.0_wp
    end select
  end subroutine material_stress

  pure subroutine material_stresses(mats, kin, lo, hi, mat, F, L, jv, sig, psi)
    !! material_stress of particles lo..hi with materials mats(mat(ip)), on plain arrays
    !! (in this module, so the models are inlined).
    type(material_t), intent(in) :: mats(:)
    integer(ik), intent(in) :: kin, lo, hi, mat(*)
    real(wp), intent(in) :: F(4, *), L(4, *), jv(*)
    real(wp), intent(inout) :: sig(4, *), psi(*)
    integer(ik) :: ip
    do ip = lo, hi
      call material_stress(mats(mat(ip)), kin, F(:, ip), L(:, ip), jv(ip), sig(:, ip), psi(ip))
    end do
  end subroutine material_stresses
end module cpdi_materials
