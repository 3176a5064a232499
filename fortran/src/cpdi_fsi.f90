!> Solids coupled two-way to the incompressible water: the step of a coupled run.
module cpdi_fsi
  !! Solids (Hencky, neo-Hookean: explicit, on the nodal grid) and rigid bodies with the
  !! incompressible water (on the MAC faces) as one continuum (docs/fsi_incompressible.md):
  !!
  !! 1. weights of every particle on the nodes (and, in incomp_step, on the face lattices);
  !! 2. the solids' explicit nodal step up to the velocity after forces: P2G of the solid
  !!    particles (mass, momentum, stress divergence, gravity), v* = v + dt f / m, rigid
  !!    nodes and walls;
  !! 3. incomp_step: the solid's mass and nodal v* join the water's on the faces, the
  !!    projection runs over the cells of water and solid with the mixture's face densities
  !!    (the pressure gradient acts on the solid's faces: buoyancy), rigid bodies' cells bound
  !!    the water with their velocity; the solid's face velocity changes return to the nodes;
  !! 4. the solid particles from their nodes (FLIP/PIC blend, positions, USL velocity gradient),
  !!    F, volume, CPDI domains and stress; rigid particles move with their prescribed velocity.
  !!
  !! Serial, and nothing is allocated per step. Water particles never touch the nodes.
  use, intrinsic :: iso_fortran_env, only: int64
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_OUTSIDE, CPDI_ERR_DOMAIN, CPDI_ERR_NAN, CPDI_ERR_JACOBIAN
  use cpdi_grid, only: grid_apply_walls, hold_on_walls, grid_box
  use cpdi_shape, only: shape_alloc, shape_compute, shape_count, shape_slot, SHAPE_FAIL_INVERTED, SHAPE_CPDI
  use cpdi_materials, only: material_stresses
  use cpdi_kinematics, only: det2, map_domains
  use cpdi_incompressible, only: incomp_step, incomp_fill_weights, COUPLING_BATTY, SUBSTEPS_IMPLICIT
  use cpdi_sim, only: sim_t
  use cpdi_grid_update, only: impose_rigid
  use cpdi_rigid_body, only: rb_begin, rb_walls, rb_move
  use cpdi_loads, only: loads_prepare, loads_rigid, loads_free
  implicit none
  private

  public :: fsi_prepare, fsi_step, fsi_finish

contains

  subroutine fsi_prepare(s, st)
    !! Nodal weights storage, the solids' stress and the signal speed of the current state.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    logical :: realloc
    real(wp) :: cs
    realloc = .not. allocated(s%sh%idx)
    if (.not. realloc) realloc = s%sh%kind /= s%opt%shape .or. size(s%sh%w, 2) /= s%p%n
    if (realloc) then
      call shape_alloc(s%sh, s%opt%shape, s%p%n, st)
      if (.not. st%ok()) return
    end if
    s%mtol = 1.0e-12_wp*minval(s%p%m)
    call loads_prepare(s%ld, s%p%n, s%g%nnodes, st)
    if (.not. st%ok()) return
    s%inc%smax_w = sqrt(2.0_wp)*maxval(abs(s%p%v)) + sqrt(norm2(s%opt%gravity)*s%g%h)
    call solid_stress(s, cs, st)
    if (.not. st%ok()) return
    s%smax = max(s%smax, cs)
  end subroutine fsi_prepare

  subroutine fsi_step(s, dt, st)
    !! One coupled step of length dt.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    type(status_t), intent(inout) :: st
    integer(ik) :: bad, fail
    real(wp) :: cs, flw, ke, mom(2), wg, vb
    character(len=300) :: buf

    call shape_compute(s%g, s%p, s%sh, bad, fail, st)
    if (.not. st%ok()) return
    if (bad /= 0) then
      if (fail == SHAPE_FAIL_INVERTED) then
        write (buf, '(a,i0,a,i0,a)') 'step ', s%steps + 1, ': CPDI domain of particle ', bad, &
          ' is inverted (r1 x r2 <= 0); reduce cfl or refine the grid'
        call st%set(CPDI_ERR_DOMAIN, trim(buf))
      else
        write (buf, '(a,i0,a,i0,a,2es12.4,a)') 'step ', s%steps + 1, ': particle ', bad, ' at (', s%p%x(:, bad), &
          ') has left the grid; enlarge [grid] size or close the wall'
        call st%set(CPDI_ERR_OUTSIDE, trim(buf))
      end if
      return
    end if
    call solid_p2g(s, dt)
    if (s%inc%submode == SUBSTEPS_IMPLICIT) call solid_compliance(s)
    call rb_begin(s%inc%rb, s%p, s%opt%gravity, dt)   ! free rigid bodies: state and gravity (cpdi_rigid_body)
    call rb_walls(s%inc%rb, s%g, s%p, dt, .true.)     ! ... and what the walls hold in the pressure solve
    s%inc%dt_corr = s%opt%cfl*s%g%h/max(s%inc%smax_w, tiny(1.0_wp))   ! the water's own step
    ! the water's PIC share is per step of its own length: a coupled step is the solid's acoustic
    ! one, up to ~100 times shorter, and (1 - flip) per step is a numerical viscosity
    ! ~ (1 - flip) h^2 / dt that would grow as the step shrinks
    flw = 1.0_wp - (1.0_wp - s%opt%flip)*min(1.0_wp, dt/s%inc%dt_corr)
    call incomp_step(s%inc, s%g, s%p, flw, s%opt%gravity, dt, s%steps, s%diag, s%timers, s%smax, st, &
                     s%g%m(:, 1), s%g%vx(:, 1), s%g%vy(:, 1), s%g%fx(:, 1), s%g%fy(:, 1))
    if (.not. st%ok()) return
    s%inc%smax_w = s%smax   ! the water's signal speed (incomp_step); the solids' joins it below
    ! the water's loads on the solids (cpdi_loads): prescribed bodies from the pressure, before they move
    if (s%any_rigid) call loads_rigid(s%ld, s%p, s%rigid, s%inc%mc, s%g, s%inc%rho, s%opt%gravity)
    ! the solid particles gather the projection's change of their face velocities with the face
    ! weights their mass went to the faces with (momentum-conserving); the force of the water
    ! on the solids is that momentum change over dt (solid_g2p)
    call solid_g2p(s, dt, st)
    if (.not. st%ok()) return
    if (s%inc%rb%n > 0) then   ! the walls hold the bodies, which then move rigidly
      call rb_walls(s%inc%rb, s%g, s%p, dt, .false.)
      call rb_move(s%inc%rb, s%p, s%opt%gravity, dt, ke, mom, wg, vb)
      call loads_free(s%ld, s%p, s%inc%rb)
      s%inc%fsolid = s%inc%fsolid + sum(s%inc%rb%force(1:2, :), dim=2)
      s%diag(4) = s%diag(4) + ke
      s%diag(6:7) = s%diag(6:7) + mom
      s%diag(8) = s%diag(8) + wg
      s%smax = max(s%smax, sqrt(2.0_wp)*vb + sqrt(norm2(s%opt%gravity)*s%g%h))
    end if
    s%dt_last = dt
    if (associated(s%sub)) return   ! the solids' substeps follow (cpdi_step), then fsi_finish
    call solid_stress(s, cs, st)
    if (.not. st%ok()) return
    s%smax = max(s%smax, cs)
  end subroutine fsi_step

  subroutine fsi_finish(s, dt, st)
    !! After the solids' substeps of a subcycled step: their kinetic energy, momentum and work of
    !! gravity over the step (diag 4, 6-8, from their positions at its start), strain energy (5),
    !! and their speed in the next step's limit.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    type(status_t), intent(inout) :: st
    integer(ik) :: k, ip
    real(wp) :: cs, ke, mom(2), wg
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    associate (p => s%p)
      do k = 1, size(s%isub)
        ip = s%isub(k)
        ke = ke + 0.5_wp*p%m(ip)*(p%v(1, ip)**2 + p%v(2, ip)**2)
        mom = mom + p%m(ip)*p%v(:, ip)
        wg = wg + p%m(ip)*dot_product(s%opt%gravity, p%x(:, ip) - s%xw(:, k))
      end do
    end associate
    s%diag(4) = s%diag(4) + ke
    s%diag(6:7) = s%diag(6:7) + mom
    s%diag(8) = s%diag(8) + wg
    call solid_stress(s, cs, st)
    if (.not. st%ok()) return
    s%smax = max(s%smax, cs)
    s%dt_last = dt
  end subroutine fsi_finish

  subroutine solid_p2g(s, dt)
    !! Nodal mass, velocity at t^n (px, py) and after the solids' forces (vx, vy): solid and
    !! rigid particles only; rigid nodes and walls imposed on both.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik) :: ip, a, k
    real(wp) :: mp, wk, gxk, gyk, vol, sig(4), b(2)
    logical :: rig, batty, vwalls, dev
    batty = s%inc%coupling == COUPLING_BATTY
    vwalls = batty .or. associated(s%sub)   ! the walls under the solid's volume constraint
    ! solid_substeps = "implicit": the in-plane deviatoric stress only; the mean stress is the
    ! projection's pressure (solid_compliance, cpdi_incompressible solid_helmholtz)
    dev = s%inc%submode == SUBSTEPS_IMPLICIT
    associate (g => s%g, p => s%p)
      if (vwalls) s%inc%svol = 0.0_wp
      g%m = 0.0_wp
      g%px = 0.0_wp
      g%py = 0.0_wp
      g%fx = 0.0_wp
      g%fy = 0.0_wp
      if (s%any_rigid) then
        g%mr = 0.0_wp
        g%prx = 0.0_wp
        g%pry = 0.0_wp
      end if
      do ip = 1, p%n
        if (s%fluid(p%mat(ip)) .or. s%inc%free(p%mat(ip))) cycle
        mp = p%m(ip)
        vol = p%vol(ip)
        sig = p%sig(:, ip)
        if (dev) sig(1:2) = sig(1:2) - 0.5_wp*(sig(1) + sig(2))
        b = mp*(s%opt%gravity + p%bf(:, ip))
        rig = s%rigid(p%mat(ip))
        do a = 1, shape_count(s%sh, ip)
          call shape_slot(s%sh, ip, a, k, wk, gxk, gyk)
          g%m(k, 1) = g%m(k, 1) + wk*mp
          g%px(k, 1) = g%px(k, 1) + wk*mp*p%v(1, ip)
          g%py(k, 1) = g%py(k, 1) + wk*mp*p%v(2, ip)
          g%fx(k, 1) = g%fx(k, 1) - vol*(sig(1)*gxk + sig(3)*gyk) + wk*b(1)
          g%fy(k, 1) = g%fy(k, 1) - vol*(sig(3)*gxk + sig(2)*gyk) + wk*b(2)
          if (vwalls) s%inc%svol(k) = s%inc%svol(k) + wk*vol
          if (rig) then
            g%mr(k, 1) = g%mr(k, 1) + wk*mp
            g%prx(k, 1) = g%prx(k, 1) + wk*mp*p%v(1, ip)
            g%pry(k, 1) = g%pry(k, 1) + wk*mp*p%v(2, ip)
          end if
        end do
      end do
      where (g%m(:, 1) > s%mtol)
        g%px(:, 1) = g%px(:, 1)/g%m(:, 1)
        g%py(:, 1) = g%py(:, 1)/g%m(:, 1)
        g%vx(:, 1) = g%px(:, 1) + dt*g%fx(:, 1)/g%m(:, 1)
        g%vy(:, 1) = g%py(:, 1) + dt*g%fy(:, 1)/g%m(:, 1)
      elsewhere
        g%m(:, 1) = 0.0_wp
        g%px(:, 1) = 0.0_wp
        g%py(:, 1) = 0.0_wp
        g%vx(:, 1) = 0.0_wp
        g%vy(:, 1) = 0.0_wp
      end where
      if (s%any_rigid) then
        call impose_rigid(g, [1_ik, g%nnodes], g%px, g%py)
        call impose_rigid(g, [1_ik, g%nnodes], g%vx, g%vy)
      end if
      if (vwalls) then
        ! the walls under the solid's volume constraint, as with contact: a solid reaching a wall
        ! node's support is held only once it fills it (otherwise a sinking block is stopped, and
        ! bounced elastically, a cell above the floor)
        s%inc%vfull = s%fullness*g%h**2
        call grid_apply_walls(g, g%px(:, 1), g%py(:, 1), s%inc%svol, s%inc%vfull)
        call grid_apply_walls(g, g%vx(:, 1), g%vy(:, 1), s%inc%svol, s%inc%vfull)
      else
        call grid_apply_walls(g, g%px(:, 1), g%py(:, 1))
        call grid_apply_walls(g, g%vx(:, 1), g%vy(:, 1))
      end if
    end associate
  end subroutine solid_p2g

  subroutine solid_compliance(s)
    !! solid_substeps = "implicit": per pressure cell, the solids' compliance phi / K (inc%cmp) and
    !! phi p^n / K (inc%cmpp), each particle's volume spread bilinearly over the cell centres as
    !! the cell fill is (cpdi_incompressible p2g_faces). p^n = -(sxx + syy) / 2, the particle's
    !! in-plane mean pressure; K = (lam + mu) (1 - ln J) / J, its derivative -J dp/dJ (Hencky in
    !! plane strain: the in-plane mean Kirchhoff stress is (lam + mu) ln J whatever the shear;
    !! (lam + mu) is the plane-strain bulk modulus E / (2 (1 + nu) (1 - 2 nu)) = K_3D + mu / 3).
    type(sim_t), intent(inout) :: s
    integer(ik) :: ip, i, kc(4)
    real(wp) :: wc(4), kp, pp, jv, av, c
    av = 1.0_wp/s%g%h**2
    s%inc%cmp = 0.0_wp
    s%inc%cmpp = 0.0_wp
    associate (p => s%p, mc => s%inc%mc)
      do ip = 1, p%n
        if (.not. s%inc%solid(p%mat(ip))) cycle
        jv = p%jbar(ip)
        kp = (s%mats(p%mat(ip))%lam + s%mats(p%mat(ip))%mu)*max(1.0_wp - log(jv), 0.1_wp)/jv
        pp = -0.5_wp*(p%sig(1, ip) + p%sig(2, ip))
        c = p%vol(ip)*av/kp
        call incomp_fill_weights(mc, s%g, p%x(:, ip), kc, wc)
        do i = 1, 4
          s%inc%cmp(kc(i)) = s%inc%cmp(kc(i)) + wc(i)*c
          s%inc%cmpp(kc(i)) = s%inc%cmpp(kc(i)) + wc(i)*c*pp
        end do
      end do
    end associate
  end subroutine solid_compliance

  subroutine solid_g2p(s, dt, st)
    !! Solid particles from their nodes: FLIP/PIC blend, positions, velocity gradient (USL),
    !! F, volume and CPDI domains; rigid particles with their prescribed velocity. Adds the
    !! solids' kinetic energy, momentum and work of gravity to the water's (diag 4, 6-8).
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, a, k, nclamp
    real(wp) :: wk, gxk, gyk, vn(2), dv(2), l(4), xo(2), dp(2), fs(2), xmin(2), xmax(2), ke, mom(2), wg, fl, f(4), t(4), j
    logical :: closed(4), sub
    character(len=300) :: buf
    fl = s%opt%flip
    sub = associated(s%sub)
    call grid_box(s%g, xmin, xmax, closed)
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    nclamp = 0
    fs = 0.0_wp
    associate (g => s%g, p => s%p)
      do ip = 1, p%n
        if (s%fluid(p%mat(ip)) .or. s%inc%free(p%mat(ip))) cycle
        xo = p%x(:, ip)
        if (s%rigid(p%mat(ip))) then
          p%v(:, ip) = s%mats(p%mat(ip))%vel
          p%L(:, ip) = 0.0_wp
          if (sub) cycle   ! subcycled: the substeps move the rigid particles (cpdi_step prepare_solids)
          p%x(:, ip) = xo + dt*p%v(:, ip)
        else
          vn = 0.0_wp
          dv = 0.0_wp
          l = 0.0_wp   ! velocity gradient [L11, L21, L12, L22] from the new nodal velocity (USL)
          do a = 1, shape_count(s%sh, ip)
            call shape_slot(s%sh, ip, a, k, wk, gxk, gyk)
            vn = vn + wk*[g%vx(k, 1), g%vy(k, 1)]
            dv = dv + wk*[g%vx(k, 1) - g%px(k, 1), g%vy(k, 1) - g%py(k, 1)]
            ! the velocity gradient from the nodes alone (the stress divergence's operator): v*
            ! plus the projection's change returned to the nodes (fx, fy: incomp_step's dvx, dvy)
            l = l + [(g%vx(k, 1) + g%fx(k, 1))*gxk, (g%vy(k, 1) + g%fy(k, 1))*gxk, &
                     (g%vx(k, 1) + g%fx(k, 1))*gyk, (g%vy(k, 1) + g%fy(k, 1))*gyk]
          end do
          dp = 0.0_wp   ! the projection's change, from the faces (a deformable solid is always mixture)
          do a = 1, shape_count(s%inc%shu, ip)
            call shape_slot(s%inc%shu, ip, a, k, wk, gxk, gyk)
            dp(1) = dp(1) + wk*s%inc%us(k)
          end do
          do a = 1, shape_count(s%inc%shv, ip)
            call shape_slot(s%inc%shv, ip, a, k, wk, gxk, gyk)
            dp(2) = dp(2) + wk*s%inc%vs(k)
          end do
          vn = vn + dp
          dv = dv + dp
          fs = fs + p%m(ip)*dp/dt
          s%ld%wl(:, ip) = [p%m(ip)*dp/dt, 0.0_wp]   ! the water's load (cpdi_loads), at the particle
          if (sub) then
            ! subcycled: the projection ran on the solid's velocity after gravity and its stress
            ! at the step's start (solid_p2g: without the stress the projection treats the solid
            ! as a liquid, which slumps at the waterline and drives a jet there); its change dp
            ! over dt is the water's force on the particle through the step, the load of the
            ! substeps that follow, which redo the stress themselves (cpdi_step subcycle_solids)
            p%aw(:, ip) = dp/dt
            cycle
          end if
          p%v(:, ip) = fl*(p%v(:, ip) + dv) + (1.0_wp - fl)*vn
          p%x(:, ip) = xo + dt*vn
          call hold_on_walls(p%x(:, ip), xmin, xmax, closed, nclamp)
          p%L(:, ip) = l
          t = [1.0_wp + dt*p%L(1, ip), dt*p%L(2, ip), dt*p%L(3, ip), 1.0_wp + dt*p%L(4, ip)]
          f = p%F(:, ip)
          p%F(:, ip) = [t(1)*f(1) + t(3)*f(2), t(2)*f(1) + t(4)*f(2), t(1)*f(3) + t(3)*f(4), t(2)*f(3) + t(4)*f(4)]
          j = det2(p%F(:, ip))
          if (.not. (j > 0.0_wp)) then
            write (buf, '(a,i0,a,i0,a,2es12.4,a,es11.3,a)') 'step ', s%steps + 1, ': solid particle ', ip, ' at (', &
              p%x(:, ip), ') has det F = ', j, ' <= 0 (material inverted); reduce cfl or refine the grid'
            call st%set(CPDI_ERR_JACOBIAN, trim(buf))
            return
          end if
          p%vol(ip) = j*p%vol0(ip)
          p%jbar(ip) = j
          if (s%opt%shape == SHAPE_CPDI) call map_domains(ip, ip, p%F, p%r0, p%r)
        end if
        ke = ke + 0.5_wp*p%m(ip)*(p%v(1, ip)**2 + p%v(2, ip)**2)
        mom = mom + p%m(ip)*p%v(:, ip)
        wg = wg + p%m(ip)*dot_product(s%opt%gravity, p%x(:, ip) - xo)
      end do
    end associate
    s%inc%fsolid = fs
    s%diag(4) = s%diag(4) + ke
    s%diag(6) = s%diag(6) + mom(1)
    s%diag(7) = s%diag(7) + mom(2)
    s%diag(8) = s%diag(8) + wg
    s%diag(12) = s%diag(12) + real(nclamp, wp)
  end subroutine solid_g2p

  subroutine solid_stress(s, cs, st)
    !! Stress and strain energy (diag 5) of the solid particles; cs: their largest signal
    !! speed c + |v| (the explicit solid's step limit), or, with the solids subcycled (s%sub),
    !! sqrt(2) |v|_max + sqrt(|g| h), the water's own measure: the water step only has to keep
    !! the solids within a cell; their substeps keep to their speed of sound (sub%smax). Also
    !! sqrt(2) max(|vx|, |vy|) of every prescribed rigid material's velocity, the water's measure
    !! of speed (a body driven through water at rest would otherwise set no limit, and one step
    !! could carry it anywhere).
    type(sim_t), intent(inout) :: s
    real(wp), intent(out) :: cs
    type(status_t), intent(inout) :: st
    integer(ik) :: ip
    real(wp) :: se, c, ca
    character(len=300) :: buf
    cs = 0.0_wp
    ca = 0.0_wp
    se = 0.0_wp
    do ip = 1, min(size(s%mats), size(s%rigid))
      if (s%rigid(ip)) cs = max(cs, sqrt(2.0_wp)*maxval(abs(s%mats(ip)%vel)))
    end do
    ca = cs   ! the substeps carry the prescribed rigid bodies too (cpdi_step prepare_solids)
    associate (p => s%p)
      do ip = 1, p%n
        if (s%fluid(p%mat(ip)) .or. s%rigid(p%mat(ip)) .or. s%inc%free(p%mat(ip))) cycle
        call material_stresses(s%mats, s%opt%kinematics, ip, ip, p%mat, p%F, p%L, p%jbar, p%sig, p%psi)
        p%psi(ip) = p%psi(ip)*p%vol0(ip)
        se = se + p%psi(ip)
        c = sqrt(s%mats(p%mat(ip))%pmod*p%vol(ip)/p%m(ip)) + norm2(p%v(:, ip))
        if (associated(s%sub)) then
          ca = max(ca, c)
          c = sqrt(2.0_wp)*max(abs(p%v(1, ip)), abs(p%v(2, ip))) + sqrt(norm2(s%opt%gravity)*s%g%h)
        end if
        if (.not. (abs(p%sig(1, ip)) + abs(p%sig(2, ip)) + abs(p%sig(3, ip)) + c < huge(1.0_wp))) then
          write (buf, '(a,i0,a,i0,a)') 'step ', s%steps + 1, ': NaN or Inf in the stress or velocity of solid particle ', &
            ip, '; the run became unstable (reduce cfl, check materials)'
          call st%set(CPDI_ERR_NAN, trim(buf))
          return
        end if
        cs = max(cs, c)
      end do
    end associate
    s%diag(5) = se
    ! the substeps' signal speed, from this state (a restart from it steps alike)
    if (associated(s%sub)) s%sub%smax = ca
  end subroutine solid_stress
end module cpdi_fsi
