!> The particle stage of the explicit step.
module cpdi_constitutive
  !! The particle stage of the explicit step: F, volume and CPDI domains from the velocity gradient
  !! (with the volumetric projection's strain increment), then stresses, energies, the signal speed
  !! and the projected mean stress.
  !! Part of the explicit step (cpdi_step holds the sequence); OpenMP as described there.
  use cpdi_kinds, only: wp, ik
  use cpdi_slots, only: DIAG_MAX_SIGNAL, DIAG_STRAIN, DIAG_VISCOUS
  use cpdi_status, only: status_t, CPDI_ERR_NAN, CPDI_ERR_JACOBIAN
  use cpdi_shape, only: SHAPE_CPDI
  use cpdi_schedule, only: NCHUNK, chunk_range, blocks_t, block_start, block_next
  use cpdi_materials, only: material_stresses, MAT_FLUID
  use cpdi_kinematics, only: det2, map_domains
  use cpdi_projection, only: projection_apply, PROJ_NONE
  use cpdi_sim, only: sim_t, all_ok
  implicit none
  private

  public :: deformation_update, projected_deformation, update_domains, stress_update, project_mean_stress

contains

  subroutine deformation_update(s, dt, st)
    !! F <- (I + dt L) F, volume J V0, CPDI domains r = F r0 (optionally scaled). With the
    !! projection on, the volumetric strain increment ln det(I + dt L) of the participating
    !! particles is left in work(1, :) for projection (rate form, Mast et al. 2012) and
    !! `projected_deformation` rebuilds J, F and the domains from it.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    type(status_t), intent(inout) :: st
    integer(ik) :: c, lo, hi, ip
    type(blocks_t) :: blk
    character(len=300) :: buf

    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, s%p%n, lo, hi)
      call deformation_block(s, dt, lo, hi, s%cbad(c), s%cval(c))
    end do
    !$omp barrier
    !$omp single
    do c = 1, NCHUNK
      ip = s%cbad(c)
      if (ip == 0) cycle
      if (s%cval(c) /= s%cval(c)) then
        write (buf, '(a,i0,a,i0,a)') 'step ', s%steps + 1, ': NaN in the velocity gradient of particle ', &
          ip, '; the run became unstable (reduce cfl, check material parameters)'
        call st%set(CPDI_ERR_NAN, trim(buf))
      else
        write (buf, '(a,i0,a,i0,a,2es12.4,a,es11.3,a)') 'step ', s%steps + 1, ': particle ', ip, ' at (', &
          s%p%x(:, ip), ') has det F = ', s%cval(c), ' <= 0 (material inverted); reduce cfl or refine the grid'
        call st%set(CPDI_ERR_JACOBIAN, trim(buf))
      end if
      exit
    end do
    !$omp end single
  end subroutine deformation_update

  subroutine deformation_block(s, dt, lo, hi, bad, jbad)
    !! deformation_update of particles lo..hi; bad is the first particle with det F <= 0
    !! or NaN (0 if none) and jbad its det F.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik), intent(in) :: lo, hi
    integer(ik), intent(out) :: bad
    real(wp), intent(out) :: jbad
    integer(ik) :: ip
    real(wp) :: a11, a21, a12, a22, f(4), j, deta
    logical :: proj

    proj = s%opt%projection /= PROJ_NONE
    bad = 0
    jbad = 0.0_wp
    associate (p => s%p)
      do ip = lo, hi
        a11 = 1.0_wp + dt*p%L(1, ip)
        a21 = dt*p%L(2, ip)
        a12 = dt*p%L(3, ip)
        a22 = 1.0_wp + dt*p%L(4, ip)
        deta = a11*a22 - a12*a21
        f = p%F(:, ip)
        if (s%fluid(p%mat(ip))) then
          ! a fluid has no memory of shear: keep only its volume ratio, F = sqrt(J) I
          j = det2(f)*deta
          p%F(:, ip) = [sqrt(max(j, 0.0_wp)), 0.0_wp, 0.0_wp, sqrt(max(j, 0.0_wp))]
        else
          p%F(1, ip) = a11*f(1) + a12*f(2)
          p%F(2, ip) = a21*f(1) + a22*f(2)
          p%F(3, ip) = a11*f(3) + a12*f(4)
          p%F(4, ip) = a21*f(3) + a22*f(4)
          j = det2(p%F(:, ip))
        end if
        if (.not. (j > 0.0_wp) .or. .not. (deta > 0.0_wp)) then
          if (bad == 0) then
            bad = ip
            jbad = j
            if (deta /= deta) jbad = deta
          end if
          cycle
        end if
        p%vol(ip) = j*p%vol0(ip)
        p%jbar(ip) = j
        if (proj) then
          p%work(1, ip) = log(deta)          ! volumetric strain increment, projected
          p%work(2, ip) = det2(f)            ! J at the start of the step
          p%work(3, ip) = p%work(1, ip)      ! raw increment, for the stabilisation
        end if
      end do
    end associate
    if (.not. proj .and. bad == 0) call update_domains(s, lo, hi)
  end subroutine deformation_block

  subroutine projected_deformation(s)
    !! J, F and volume of the participating particles from the projected strain increment
    !! (fluids F = sqrt(J) I, solids F <- sqrt(J~/J) F: plane-strain F-bar), then every
    !! domain. Stabilisation: the increment used is (1 - beta) projected + beta raw. A full
    !! projection gives sub-cell (hourglass) motions of a fluid no volumetric stiffness at
    !! all; over seconds they grow and the water collapses into itself (measured: a resting
    !! tank gained 2.7 kJ of kinetic energy in 4 s). beta keeps a stiffness beta K for them.
    type(sim_t), intent(inout) :: s
    integer(ik) :: c, lo, hi, ip
    type(blocks_t) :: blk
    real(wp) :: jn
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, s%p%n, lo, hi)
      do ip = lo, hi
        if (s%pmask(ip)) then
          jn = s%p%work(2, ip)*exp((1.0_wp - s%opt%pstab)*s%p%work(1, ip) + s%opt%pstab*s%p%work(3, ip))
          if (s%fluid(s%p%mat(ip))) then
            s%p%F(:, ip) = [sqrt(jn), 0.0_wp, 0.0_wp, sqrt(jn)]
          else
            s%p%F(:, ip) = s%p%F(:, ip)*sqrt(jn/s%p%jbar(ip))
          end if
          s%p%vol(ip) = jn*s%p%vol0(ip)
          s%p%jbar(ip) = jn
        end if
      end do
      call update_domains(s, lo, hi)
    end do
    !$omp barrier
  end subroutine projected_deformation

  subroutine update_domains(s, lo, hi)
    !! CPDI domains of particles lo..hi from their F (domain_block).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: lo, hi
    if (s%opt%shape /= SHAPE_CPDI) return
    call domain_block(lo, hi, s%p%F, s%p%r0, s%opt%domain_scaling == 1, s%opt%lcrit*s%g%h, s%p%r)
  end subroutine update_domains

  subroutine domain_block(lo, hi, f, r0, scaled, lc, r)
    !! r = F r0 (map_domains) for particles lo..hi, with optional Homel et al. (2016)
    !! scaling: diagonals longer than lc are shortened to lc.
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(in) :: f(4, *), r0(4, *), lc
    logical, intent(in) :: scaled
    real(wp), intent(inout) :: r(4, *)
    integer(ik) :: ip
    real(wp) :: la(2), lb(2), na, nb
    call map_domains(lo, hi, f, r0, r)
    if (.not. scaled) return
    do ip = lo, hi
      la = r(1:2, ip) + r(3:4, ip)
      lb = r(1:2, ip) - r(3:4, ip)
      na = norm2(la)
      nb = norm2(lb)
      if (na > lc .or. nb > lc) then
        if (na > lc) la = la*(lc/na)
        if (nb > lc) lb = lb*(lc/nb)
        r(1:2, ip) = 0.5_wp*(la + lb)
        r(3:4, ip) = 0.5_wp*(la - lb)
      end if
    end do
  end subroutine domain_block

  subroutine stress_update(s, st)
    !! Stress and energy of every particle; signal speed for the next step.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: c, lo, hi, ip
    type(blocks_t) :: blk
    character(len=300) :: buf

    ! max signal speed and min viscous step per block (cext), reduced in the single: max
    ! and min are exact, so this is the value of any other reduction order.
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, s%p%n, lo, hi)
      s%cext(:, c) = [0.0_wp, huge(1.0_wp)]
      call stress_block(s, lo, hi, s%red(:, c), s%cext(1, c), s%cext(2, c), s%cbad(c))
    end do
    !$omp barrier
    !$omp single
    do c = 1, NCHUNK
      ip = s%cbad(c)
      if (ip == 0) cycle
      write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', s%steps + 1, ': NaN or Inf in the stress or velocity '// &
        'of particle ', ip, ' at (', s%p%x(:, ip), '); the run became unstable (reduce cfl, check materials)'
      call st%set(CPDI_ERR_NAN, trim(buf))
      exit
    end do
    if (st%ok()) then
      s%diag(DIAG_STRAIN) = sum(s%red(1, :))
      s%diag(DIAG_VISCOUS) = s%diag(DIAG_VISCOUS) + sum(s%red(2, :))*s%dt_last
      s%smax = maxval(s%cext(1, :))
      s%visc_dt = minval(s%cext(2, :))
      s%diag(DIAG_MAX_SIGNAL) = s%smax
    end if
    !$omp end single
  end subroutine stress_update

  subroutine stress_block(s, lo, hi, red, smax, vdt, bad)
    !! Stress of particles lo..hi; red(1:2) = [strain energy, viscous dissipation rate] of
    !! the block; smax, vdt: running max signal speed and min viscous step; bad: the first
    !! particle with a non-finite stress or velocity (0 if none).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(out) :: red(6)
    real(wp), intent(inout) :: smax, vdt
    integer(ik), intent(out) :: bad
    integer(ik) :: ip, im
    real(wp) :: se, c, rho, vmag, sig(4), dis, tr3
    logical :: proj

    proj = s%opt%projection /= PROJ_NONE
    se = 0.0_wp
    dis = 0.0_wp
    bad = 0
    associate (p => s%p)
      call material_stresses(s%mats, s%opt%kinematics, lo, hi, p%mat, p%F, p%L, p%jbar, p%sig, p%psi)
      do ip = lo, hi
        im = p%mat(ip)
        sig = p%sig(:, ip)
        p%psi(ip) = p%psi(ip)*p%vol0(ip)
        se = se + p%psi(ip)
        rho = p%m(ip)/p%vol(ip)
        vmag = sqrt(p%v(1, ip)**2 + p%v(2, ip)**2)
        c = sqrt(s%mats(im)%pmod/rho) + vmag
        if (.not. (abs(sig(1)) + abs(sig(2)) + abs(sig(3)) + c < huge(1.0_wp))) then
          if (bad == 0) bad = ip
          cycle
        end if
        smax = max(smax, c)
        if (s%devonly) then
          ! implicit substeps (cpdi_step subcycle_solids): the water step's projection carries the
          ! solid's mean pressure (in the body force aw), its backward-Euler path from p^n (work(1))
          ! to the projection's p^n+1 (work(2)); the substeps' stress is the full stress plus that
          ! path's pressure at this time, so they add only the deviator and the stiffness of the
          ! volume's deviation from the path
          tr3 = min(max((s%t + s%dt_last - s%sub_t0)/s%sub_dt, 0.0_wp), 1.0_wp)
          tr3 = p%work(1, ip) + tr3*(p%work(2, ip) - p%work(1, ip))
          p%sig(1, ip) = sig(1) + tr3
          p%sig(2, ip) = sig(2) + tr3
        end if
        if (proj) then   ! the mean stress, for project_mean_stress
          p%work(1, ip) = (sig(1) + sig(2) + sig(4))/3.0_wp
          p%work(2, ip) = p%work(1, ip)
        end if
        if (s%mats(im)%model == MAT_FLUID .and. s%mats(im)%visc > 0.0_wp) then
          vdt = min(vdt, 0.5_wp*rho*s%g%h**2/s%mats(im)%visc)
          ! viscous dissipation 2 mu dev(D):dev(D) V (plane strain, D_zz = 0)
          tr3 = (p%L(1, ip) + p%L(4, ip))/3.0_wp
          dis = dis + 2.0_wp*s%mats(im)%visc*p%vol(ip)*((p%L(1, ip) - tr3)**2 + (p%L(4, ip) - tr3)**2 + tr3**2 &
                                                        + 0.5_wp*(p%L(2, ip) + p%L(3, ip))**2)
        end if
      end do
    end associate
    red = [se, dis, 0.0_wp, 0.0_wp, 0.0_wp, 0.0_wp]
  end subroutine stress_block

  subroutine project_mean_stress(s, st)
    !! Replace the mean stress (sxx + syy + szz)/3 of the participating particles, left in
    !! work(1:2, :) by stress_update, by its projection (blended with beta of the particle's
    !! own, see projected_deformation); the deviatoric stress is left as it is. Uses the
    !! operator set up for this step.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: c, lo, hi, ip
    type(blocks_t) :: blk
    real(wp) :: dm
    call projection_apply(s%proj, s%opt%shape, s%g, s%p, s%pmask, s%p%work(1, :), st, s%sp)
    if (.not. all_ok(st)) return   ! a status set in a single: every thread must leave here
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, s%p%n, lo, hi)
      do ip = lo, hi
        if (.not. s%pmask(ip)) cycle
        dm = (1.0_wp - s%opt%pstab)*(s%p%work(1, ip) - s%p%work(2, ip))
        s%p%sig(1, ip) = s%p%sig(1, ip) + dm
        s%p%sig(2, ip) = s%p%sig(2, ip) + dm
        s%p%sig(4, ip) = s%p%sig(4, ip) + dm
      end do
    end do
    !$omp barrier
  end subroutine project_mean_stress
end module cpdi_constitutive
