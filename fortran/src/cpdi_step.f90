!> The explicit MPM step and the water-model dispatch: the sequence of a step's stages.
module cpdi_step
  !! One step: time step from the signal speed, interpolation weights, particle-to-grid
  !! transfer, grid momentum update with walls and rigid nodes, grid-to-particle
  !! transfer (USL or MUSL), deformation update (F, volume, CPDI domains), stress.
  !! Fluid particles keep an isotropic F = sqrt(J) I: a Newtonian fluid's stress depends
  !! on J and the rate D only, and an accumulated total shear would distort (and
  !! eventually invert) their CPDI domains without physical meaning.
  !! Diagnostics are accumulated inside the same loops; nothing is allocated per step.
  !!
  !! OpenMP: one parallel region per step (sim_step); the phases are orphaned worksharing
  !! constructs, so they also run serially when called outside a region (sim_prepare).
  !! Every particle loop runs over the fixed blocks of cpdi_schedule (gathers, reductions
  !! summed block by block in a fixed order, max/min per block; each thread runs its own
  !! range of blocks and then helps the others: block_start, block_next) and every scatter to the
  !! grid over its two-colour strips, so a run gives the same bits at any thread count.
  !! Node loops are static worksharing loops. Contact, walls, reductions and error scans
  !! run in `single` (they touch few nodes). Locals of a phase routine are private to each
  !! thread; anything shared lives in sim_t.
  !!
  !! Stages: cpdi_transfer (P2G, G2P, MUSL remap), cpdi_grid_update (forces, walls, contact),
  !! cpdi_constitutive (F, domains, stress, projection of the mean stress); incompressible
  !! water replaces the whole sequence by cpdi_incompressible (sim_step: the one place where
  !! the two water models part).
  use, intrinsic :: iso_fortran_env, only: int64
  !$ use omp_lib, only: omp_get_max_threads, omp_set_num_threads
  use cpdi_kinds, only: wp, ik
  use cpdi_slots, only: DIAG_DT, DIAG_MASS, DIAG_MAX_SIGNAL, DIAG_STEPS, DIAG_T, TIMER_DEFORMATION, &
                        TIMER_G2P, TIMER_GRID, TIMER_P2G, TIMER_PROJECTION, TIMER_SHAPE, TIMER_STRESS
  use cpdi_status, only: status_t, CPDI_ERR_INPUT, CPDI_ERR_STATE, CPDI_ERR_OUTSIDE, CPDI_ERR_DOMAIN, &
                         CPDI_ERR_CFL
  use cpdi_grid, only: grid_fields, grid_init
  use cpdi_particles, only: particles_alloc
  use cpdi_materials, only: MAT_RIGID_BODY
  use cpdi_shape, only: shape_alloc, shape_compute, SHAPE_GIMP, SHAPE_FAIL_INVERTED
  use cpdi_schedule, only: strips_alloc, strips_build, blocks_region, blocks_enter, MAX_THREADS
  use cpdi_projection, only: projection_alloc, projection_setup, projection_apply, PROJ_NONE
  use cpdi_incompressible, only: incomp_prepare, incomp_step, FLUID_INCOMPRESSIBLE, incomp_pressure_at, &
                                 SUBSTEPS_OFF, SUBSTEPS_EXPLICIT, SUBSTEPS_IMPLICIT, SUBSTEPS_AUTO
  use cpdi_fsi, only: fsi_prepare, fsi_step, fsi_finish
  use cpdi_motion, only: motion_apply
  use cpdi_sim, only: sim_t, all_ok, all_int, tic_master, toc_master, MIN_PER_THREAD, PROBE_MIN, PROBE_MAX, &
                      PROBE_COST, UPDATE_USL
  use cpdi_grid_update, only: node_range, grid_update
  use cpdi_transfer, only: p2g, g2p
  use cpdi_constitutive, only: deformation_update, projected_deformation, stress_update, project_mean_stress
  implicit none
  private

  public :: sim_prepare, sim_step, sim_stable_dt, probe_cap, sim_check_inside, sim_release

  integer(ik), parameter :: MAX_SUBSTEPS = 100000   !! solid substeps in one water step before a run is refused

contains

  recursive subroutine sim_prepare(s, st)
    !! Check the pieces fit together and bring derived state up to date. Called before
    !! stepping whenever grid, materials, particles or options changed.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: ip
    character(len=200) :: buf
    real(wp) :: lp(2)
    logical :: realloc

    if (.not. (s%has_grid .and. s%has_materials .and. s%has_particles)) then
      call st%set(CPDI_ERR_STATE, 'set the grid, the materials and the particles before stepping')
      return
    end if
    if (any(s%p%mat < 1) .or. any(s%p%mat > size(s%mats))) then
      ip = findloc((s%p%mat < 1) .or. (s%p%mat > size(s%mats)), .true., 1)
      write (buf, '(a,i0,a,i0,a,i0,a)') 'particle ', ip, ' has material ', s%p%mat(ip), &
        ' but only ', size(s%mats), ' materials are defined'
      call st%set(CPDI_ERR_INPUT, trim(buf))
      return
    end if
    if (s%opt%shape == SHAPE_GIMP) then
      do ip = 1, s%p%n
        lp = [abs(s%p%r0(1, ip)) + abs(s%p%r0(3, ip)), abs(s%p%r0(2, ip)) + abs(s%p%r0(4, ip))]
        if (any(lp > 0.5_wp*s%g%h*(1.0_wp + 1.0e-12_wp)) .or. any(.not. (lp > 0.0_wp))) then
          write (buf, '(a,i0,a,2es11.3,a,es11.3,a)') 'particle ', ip, ' has GIMP half-widths ', lp, &
            ' but uGIMP needs 0 < half-width <= h/2 = ', 0.5_wp*s%g%h, '; use 1 or more particles per cell'
          call st%set(CPDI_ERR_INPUT, trim(buf))
          return
        end if
      end do
    end if
    call prepare_fields(s, st)
    if (.not. st%ok()) return
    if (s%opt%fluid /= FLUID_INCOMPRESSIBLE .and. any(s%mats(s%p%mat)%model == MAT_RIGID_BODY)) then
      call st%set(CPDI_ERR_INPUT, 'a rigid_body material (a free rigid body) moves with the incompressible water '// &
                  'only; set [solver] fluid = "incompressible", or use model = "rigid" with a prescribed velocity')
      return
    end if
    if (s%opt%fluid == FLUID_INCOMPRESSIBLE) then
      call prepare_incompressible(s, st)
      return
    end if
    call ensure_shape(s, st)
    if (.not. st%ok()) return
    realloc = .not. allocated(s%sp%perm)
    if (.not. realloc) realloc = size(s%sp%perm) /= s%p%n .or. size(s%sp%start) /= s%g%nn(2) + 2
    if (realloc) then
      call strips_alloc(s%sp, s%p%n, s%g%nn(2), st)
      if (.not. st%ok()) return
    end if
    if (s%opt%projection /= PROJ_NONE) then
      realloc = .not. allocated(s%proj%hd)
      if (.not. realloc) realloc = size(s%proj%hd) /= s%g%nnodes .or. size(s%proj%qc, 2) /= s%p%n
      if (realloc) call projection_alloc(s%proj, s%g, s%p%n, st)
      if (.not. st%ok()) return
      if (allocated(s%pmask)) deallocate (s%pmask)
      allocate (s%pmask(s%p%n))
      s%pmask = s%mats(s%p%mat)%project
    end if
    call get_environment_variable('CPDI_MIN_PER_THREAD', buf, status=ip)
    if (ip == 0) then
      read (buf, *, iostat=ip) s%min_per_thread
      if (ip /= 0 .or. s%min_per_thread < 1) s%min_per_thread = MIN_PER_THREAD
    end if
    s%mtol = 1.0e-12_wp*minval(s%p%m)
    s%diag(DIAG_MASS) = sum(s%p%m)
    s%kprev = [1_ik, s%g%nnodes]   ! the whole grid may hold values: the next step clears it all
    if (s%smax < 0.0_wp) then   ! stress and signal speed of the current state
      if (s%opt%projection /= PROJ_NONE) then   ! its operator needs every support in the grid
        call sim_check_inside(s, st)
        if (st%ok()) call projection_setup(s%proj, s%opt%projection, s%opt%shape, s%g, s%p, s%pmask, st)
      end if
      if (st%ok()) call stress_update(s, st)
      if (st%ok() .and. s%opt%projection /= PROJ_NONE) call project_mean_stress(s, st)
    end if
  end subroutine sim_prepare

  subroutine ensure_shape(s, st)
    !! Storage of the run's interpolation weights, (re)allocated for its shape and particles.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    logical :: realloc
    ! (Fortran does not short-circuit .or.: test allocation before asking for a size)
    realloc = .not. allocated(s%sh%idx)
    if (.not. realloc) realloc = s%sh%kind /= s%opt%shape .or. size(s%sh%w, 2) /= s%p%n
    if (realloc) call shape_alloc(s%sh, s%opt%shape, s%p%n, st)
  end subroutine ensure_shape

  subroutine sim_check_inside(s, st)
    !! Weights of the current configuration (serially), refusing it if a particle's support
    !! is outside the grid or a CPDI domain is inverted. Every step makes this check first;
    !! the entry points that use the configuration outside a step make it here (the
    !! projection at preparation, cpdi_project, cpdi_get_shape): without it, a particle
    !! beyond the grid would be projected in the clamped edge cell, silently.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: bad, fail
    call ensure_shape(s, st)
    if (.not. st%ok()) return
    call shape_compute(s%g, s%p, s%sh, bad, fail, st)
    if (st%ok() .and. bad /= 0) call refuse_shape(s, bad, fail, '', 'lies outside the grid', st)
  end subroutine sim_check_inside

  subroutine refuse_shape(s, bad, fail, prefix, verb, st)
    !! The error for particle bad, whose weights failed with SHAPE_FAIL_* cause fail:
    !! prefix (where), verb ('has left the grid' in a step, 'lies outside the grid' before one).
    type(sim_t), intent(in) :: s
    integer(ik), intent(in) :: bad, fail
    character(len=*), intent(in) :: prefix, verb
    type(status_t), intent(inout) :: st
    character(len=300) :: buf
    if (fail == SHAPE_FAIL_INVERTED) then
      write (buf, '(2a,i0,a,2es12.4,a)') prefix, 'CPDI domain of particle ', bad, ' at (', s%p%x(:, bad), &
        ') is inverted (r1 x r2 <= 0); reduce cfl or refine the grid'
      call st%set(CPDI_ERR_DOMAIN, trim(buf))
    else
      write (buf, '(2a,i0,a,2es12.4,4a)') prefix, 'particle ', bad, ' at (', s%p%x(:, bad), ') ', verb, &
        '; enlarge [grid] size, close the wall, or enable domain_scaling for stretched CPDI domains'
      call st%set(CPDI_ERR_OUTSIDE, trim(buf))
    end if
  end subroutine refuse_shape

  recursive subroutine prepare_incompressible(s, st)
    !! The incompressible water model's checks and storage; signal speed of the state.
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    if (s%contact) then
      call st%set(CPDI_ERR_INPUT, 'contact is not available with fluid = "incompressible" (solids couple '// &
                  'to it as one continuum with a no-slip interface; slip interfaces are not built yet); '// &
                  'set [contact] enabled = false or use fluid = "weakly_compressible"')
      return
    end if
    if (s%opt%projection /= PROJ_NONE) then
      call st%set(CPDI_ERR_INPUT, 'the volumetric projection is for the weakly compressible model: '// &
                  'incompressible water needs none; set [solver] projection = "none"')
      return
    end if
    if (allocated(s%body)) then
      call incomp_prepare(s%inc, s%g, s%p, s%mats, s%opt%shape, s%opt%damping, st, s%body)
    else
      call incomp_prepare(s%inc, s%g, s%p, s%mats, s%opt%shape, s%opt%damping, st)
    end if
    if (.not. st%ok()) return
    s%diag(DIAG_MASS) = sum(s%p%m)
    if (s%smax < 0.0_wp) s%smax = sqrt(2.0_wp)*maxval(abs(s%p%v)) + sqrt(norm2(s%opt%gravity)*s%g%h)
    s%visc_dt = huge(1.0_wp)
    if (s%inc%visc > 0.0_wp) s%visc_dt = 0.25_wp*s%inc%rho*s%g%h**2/s%inc%visc
    if (s%inc%coupled) then   ! solids coupled to the water (cpdi_fsi), subcycled if chosen
      call prepare_solids(s, st)
      if (.not. st%ok()) call sim_release(s)   ! no half-built substeps' simulation is stepped
      if (st%ok()) call fsi_prepare(s, st)
    end if
  end subroutine prepare_incompressible

  recursive subroutine prepare_solids(s, st)
    !! The deformable solids' own simulation (s%sub) when [solver] solid_substeps is on: their
    !! particles alone on the same grid, with the explicit step of the weakly compressible model
    !! (USL, the run's shape, kinematics, cfl, flip and gravity; no damping, contact or
    !! projection). Its walls obey the solid's volume constraint (one contact field: a body lands
    !! on the floor, not a cell above it). None without a deformable solid.
    !! Prescribed rigid bodies (model "rigid") are in it too, after the deformable particles
    !! (isub(nsub+1:)), with their velocity tables: their nodes hold the solid in every substep as
    !! they do in the explicit step (impose_rigid), e.g. the anchor that clamps a plate. The
    !! substeps move them (the coupled step leaves them where they are, cpdi_fsi solid_g2p), and
    !! only their position and velocity come back (docs/notes/fsi_subcycling.md, "Prescribed rigid
    !! bodies in the substeps"). Also resolves solid_substeps = "auto" into the mode the run steps
    !! with (inc%submode).
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: ip, k, n
    logical :: keep(s%p%n), rig(s%p%n)
    call sim_release(s)
    s%inc%subcycled = .false.
    s%inc%submode = SUBSTEPS_OFF
    if (s%inc%substeps == SUBSTEPS_OFF) return
    keep = s%inc%solid(s%p%mat)
    rig = s%rigid(s%p%mat)
    if (count(keep) == 0) return   ! no deformable solid (water alone, rigid bodies only): nothing to subcycle
    n = count(keep) + count(rig)
    s%inc%submode = s%inc%substeps
    if (s%inc%substeps == SUBSTEPS_AUTO) then
      ! the coupling's choice: the volumetric stress implicit in the projection (the added-mass
      ! stable mode: a light free body floats), except for a solid held by a prescribed rigid body
      ! (elastic_obstacle's anchored plate rings and blows up under implicit,
      ! docs/notes/fsi_subcycling.md), which steps explicitly
      s%inc%submode = SUBSTEPS_IMPLICIT
      if (count(rig) > 0) s%inc%submode = SUBSTEPS_EXPLICIT
    end if
    allocate (s%sub)
    allocate (s%isub(n), s%xw(2, n))
    k = 0
    do ip = 1, s%p%n
      if (.not. keep(ip)) cycle
      k = k + 1
      s%isub(k) = ip
    end do
    s%nsub = k
    do ip = 1, s%p%n
      if (.not. rig(ip)) cycle
      k = k + 1
      s%isub(k) = ip
    end do
    associate (u => s%sub)
      call grid_init(u%g, s%g%origin, s%g%ncell, s%g%h, s%g%walls, st)
      if (.not. st%ok()) return
      u%has_grid = .true.
      allocate (u%mats(size(s%mats)), u%rigid(size(s%mats)), u%fluid(size(s%mats)))
      u%mats = s%mats
      u%rigid = s%rigid
      u%fluid = s%fluid
      u%any_rigid = s%nsub < n
      if (allocated(s%vtab)) u%vtab = s%vtab   ! the substeps give the rigid bodies their tables' motion
      u%has_materials = .true.
      call particles_alloc(u%p, n, st)
      if (.not. st%ok()) return
      u%p%m = s%p%m(s%isub)
      u%p%vol0 = s%p%vol0(s%isub)
      u%p%r0 = s%p%r0(:, s%isub)
      u%p%mat = s%p%mat(s%isub)
      call to_sub(s, 1.0_wp)
      u%has_particles = .true.
      allocate (u%body(n))
      u%body = 1
      u%contact = .true.   ! one field: the walls' volume constraint only (nothing to contact)
      u%devonly = s%inc%submode == SUBSTEPS_IMPLICIT   ! the volumetric stress is the projection's
      u%fullness = s%fullness
      u%opt = s%opt
      u%opt%fluid = 0
      u%opt%update = UPDATE_USL
      u%opt%projection = PROJ_NONE
      u%opt%damping = 0.0_wp
      u%opt%fixed_dt = 0
      u%min_per_thread = s%min_per_thread
      u%t = s%t
      u%smax = -1.0_wp
      call sim_prepare(u, st)
    end associate
    s%inc%subcycled = st%ok()
    if (.not. st%ok()) s%inc%submode = SUBSTEPS_OFF
  end subroutine prepare_solids

  recursive subroutine sim_release(s)
    !! Free the solids' own simulation, if any.
    type(sim_t), intent(inout) :: s
    if (associated(s%sub)) then
      call sim_release(s%sub)
      deallocate (s%sub)
    end if
    s%sub => null()
    if (allocated(s%isub)) deallocate (s%isub)
    if (allocated(s%xw)) deallocate (s%xw)
    s%nsub = 0
  end subroutine sim_release

  subroutine to_sub(s, dt)
    !! The solids' state into their own simulation; their body force with the water's (aw) of
    !! this water step's projection (of length dt).
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik) :: k
    associate (u => s%sub, i => s%isub)
      u%p%x = s%p%x(:, i)
      u%p%v = s%p%v(:, i)
      u%p%F = s%p%F(:, i)
      u%p%L = s%p%L(:, i)
      u%p%sig = s%p%sig(:, i)
      if (u%devonly) then
        ! the in-plane deviator (the projection's pressure is the mean stress); the path of the
        ! mean pressure the projection carries, p^n (work(1)) to its p^n+1 (work(2); cpdi_constitutive)
        u%p%work(1, :) = -0.5_wp*(s%p%sig(1, i) + s%p%sig(2, i))
        u%p%sig(1, :) = s%p%sig(1, i) + u%p%work(1, :)
        u%p%sig(2, :) = s%p%sig(2, i) + u%p%work(1, :)
        do k = 1, s%nsub
          u%p%work(2, k) = incomp_pressure_at(s%inc, s%g, s%p%x(:, i(k)))
        end do
        u%p%work(:, s%nsub + 1:) = 0.0_wp   ! rigid particles: no stress
        u%sub_t0 = s%t
      end if
      u%p%r = s%p%r(:, i)
      u%p%vol = s%p%vol(i)
      u%p%psi = s%p%psi(i)
      u%p%jbar = s%p%jbar(i)
      u%p%bf = s%p%bf(:, i) + s%p%aw(:, i)
      u%sub_dt = dt
    end associate
  end subroutine to_sub

  recursive subroutine subcycle_solids(s, dt, st)
    !! The solids' explicit steps over the water's step dt (as many as their own stable step
    !! needs, the last one landing on t + dt), under gravity, their body forces and the water's
    !! force of this step's projection (p%aw, cpdi_fsi); then their state back here.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    type(status_t), intent(inout) :: st
    real(wp) :: tend
    integer(ik) :: k, code
    character(len=600) :: buf
    call to_sub(s, dt)
    associate (u => s%sub, i => s%isub)
      s%xw = u%p%x
      u%t = s%t
      tend = s%t + dt
      k = 0
      do while (tend - u%t > 1.0e-12_wp*dt)
        call sim_step(u, tend - u%t, st)
        if (.not. st%ok()) then   ! the substep's message, told as this water step's
          code = st%code
          write (buf, '(a,i0,2a)') 'step ', s%steps + 1, ', solid substep: ', trim(st%msg)
          call st%clear()
          call st%set(code, trim(buf))
          return
        end if
        k = k + 1
        if (k > MAX_SUBSTEPS) then
          write (buf, '(a,i0,a,i0,a)') 'step ', s%steps + 1, ': the solids needed more than ', MAX_SUBSTEPS, &
            ' explicit substeps in one water step; a solid is too stiff for this grid (lower its modulus, '// &
            'use model = "rigid_body" or [solver] solid_substeps = "off")'
          call st%set(CPDI_ERR_CFL, trim(buf))
          return
        end if
      end do
      s%p%x(:, i) = u%p%x   ! the rigid particles' positions and velocities too (the substeps move them)
      s%p%v(:, i) = u%p%v
      associate (d => i(1:s%nsub), n => s%nsub)   ! the rest is the deformable particles' only
        s%p%F(:, d) = u%p%F(:, 1:n)
        s%p%L(:, d) = u%p%L(:, 1:n)
        s%p%sig(:, d) = u%p%sig(:, 1:n)
        s%p%r(:, d) = u%p%r(:, 1:n)
        s%p%vol(d) = u%p%vol(1:n)
        s%p%psi(d) = u%p%psi(1:n)
        s%p%jbar(d) = u%p%jbar(1:n)
      end associate
    end associate
  end subroutine subcycle_solids

  subroutine prepare_fields(s, st)
    !! One velocity field, or one per contact group when contact is on. A field made only
    !! of rigid particles acts as an infinite mass in contact; rigid particles inside a
    !! deformable field clamp that field's nodes (e.g. an anchored obstacle).
    type(sim_t), intent(inout) :: s
    type(status_t), intent(inout) :: st
    integer(ik) :: nf, b
    if (.not. allocated(s%body)) then
      allocate (s%body(s%p%n))
      s%body = 1
    end if
    if (size(s%body) /= s%p%n) then
      call st%set(CPDI_ERR_STATE, 'the body indices do not match the particles; set bodies after particles')
      return
    end if
    nf = 1
    if (s%contact) nf = maxval(s%body)
    if (allocated(s%field)) deallocate (s%field, s%field_rigid, s%field_solid)
    allocate (s%field(s%p%n), s%field_rigid(nf), s%field_solid(nf))
    s%field = 1
    if (s%contact) s%field = s%body
    s%field_rigid = .false.
    s%field_solid = .false.
    if (s%contact) then
      do b = 1, nf
        s%field_rigid(b) = all(pack(s%rigid(s%p%mat), s%body == b)) .and. any(s%body == b)
        s%field_solid(b) = .not. any(pack(s%fluid(s%p%mat), s%body == b))
      end do
    end if
    call grid_fields(s%g, nf, s%any_rigid, s%contact, st)
  end subroutine prepare_fields

  pure real(wp) function sim_stable_dt(s)
    !! Largest stable explicit step, h / max(c + |v|), and the viscous limit.
    type(sim_t), intent(in) :: s
    sim_stable_dt = min(s%g%h/max(s%smax, tiny(1.0_wp)), s%visc_dt)
  end function sim_stable_dt

  recursive subroutine sim_step(s, dt_cap, st)
    !! Advance by one explicit step of at most dt_cap.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt_cap
    type(status_t), intent(inout) :: st
    real(wp) :: dt, dtc
    integer(ik) :: bad, fail
    integer :: nthr, team, maxthr
    integer(int64) :: c0, c1, rate
    integer(int64) :: t0
    character(len=300) :: buf
    logical :: proj


    dtc = sim_stable_dt(s)
    if (s%opt%fixed_dt == 1) then
      dt = s%opt%dt
      if (dt > dtc) then
        write (buf, '(a,i0,a,es11.4,a,es11.4,a)') 'step ', s%steps + 1, ': fixed dt = ', dt, &
          ' s exceeds the stable limit h/max(c+|v|) = ', dtc, ' s; reduce [solver] dt or use cfl'
        call st%set(CPDI_ERR_CFL, trim(buf))
        return
      end if
    else
      dt = s%opt%cfl*dtc
    end if
    ! Incompressible water lands on dt_cap in equal steps rather than with a sliver of a
    ! step: its pressure also removes the divergence the transfer leaves (a fixed impulse
    ! per step), so a step of dt -> 0 would show a pressure ~ 1/dt (measured: wall pressure
    ! spikes of 1e3 rho g H at the steps that land on output times). The runner asks it not
    ! to land at all except at t_end (cpdi_advance, land = 0).
    if (s%opt%fluid == FLUID_INCOMPRESSIBLE .and. dt_cap > dt .and. dt_cap < 1.0e6_wp*dt) &
      dt = dt_cap/real(ceiling(dt_cap/dt*(1.0_wp - 1.0e-12_wp)), wp)
    dt = min(dt, dt_cap)
    if (.not. (dt > 0.0_wp)) then
      call st%set(CPDI_ERR_STATE, 'time step is zero; check material moduli and densities')
      return
    end if
    if (allocated(s%vtab)) call motion_apply(s%vtab, s%t, dt, s%mats, s%p, s%inc%rvel)   ! velocity tables
    proj = s%opt%projection /= PROJ_NONE
    if (s%opt%fluid == FLUID_INCOMPRESSIBLE) then
      ! The water's step runs many short parallel regions (its transfers, the multigrid): beside
      ! a busy process a thread waiting at their barriers can make two threads far slower than
      ! one. The same choice as the explicit step (team_for_step): the faster team by measured
      ! step time, the other probed now and then. Results do not depend on the team (bitwise).
      ! (No particles-per-thread floor: the water's loops have their own size thresholds, and
      ! the measured choice covers small runs too.)
      maxthr = 1
      !$ maxthr = omp_get_max_threads()
      team = team_for_step(s, maxthr)
      !$ if (abs(team) == 1) call omp_set_num_threads(1)
      call system_clock(c0)
      if (s%inc%coupled) then
        call fsi_step(s, dt, st)   ! the water's step, and its force on the solids (p%aw)
      else
        call incomp_step(s%inc, s%g, s%p, s%opt%flip, s%opt%gravity, dt, s%steps, s%diag, s%timers, s%smax, st)
      end if
      call system_clock(c1, rate)
      !$ if (abs(team) == 1) call omp_set_num_threads(maxthr)
      if (st%ok() .and. team /= 0) call team_measured(s, team, real(c1 - c0, wp)/real(rate, wp))
      if (s%inc%coupled .and. associated(s%sub)) then   ! the deformable solids' own steps under that force
        if (st%ok()) call subcycle_solids(s, dt, st)
        if (st%ok()) call fsi_finish(s, dt, st)
      end if
      if (.not. st%ok()) return
      s%diag(DIAG_MAX_SIGNAL) = s%smax
      s%dt_last = dt
      call advance_clock(s, dt)
      return
    end if

    ! One parallel region per step: every phase is orphaned worksharing (cpdi_schedule),
    ! serial pieces run in `single`, timers on the master thread. The locals passed to
    ! step_phases are shared in the region; a failing phase returns from every thread (all
    ! see the same st after the phase's barrier).
    nthr = 1
    !$ nthr = max(1, min(omp_get_max_threads(), s%p%n/max(1, s%min_per_thread), MAX_THREADS))
    team = team_for_step(s, nthr)
    if (abs(team) == 1) nthr = 1
    call blocks_region()
    call system_clock(c0)
    !$omp parallel default(shared) num_threads(nthr)
    call step_phases(s, dt, proj, st, bad, fail, buf, t0)
    !$omp end parallel
    call system_clock(c1, rate)
    if (.not. st%ok()) return
    if (team /= 0) call team_measured(s, team, real(c1 - c0, wp)/real(rate, wp))
    call advance_clock(s, dt)
  end subroutine sim_step

  subroutine step_phases(s, dt, proj, st, bad, fail, buf, t0)
    !! The phases of sim_step, called by every thread of its parallel region. bad, fail,
    !! buf and t0 are sim_step's (shared) work variables.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    logical, intent(in) :: proj
    type(status_t), intent(inout) :: st
    integer(ik), intent(inout) :: bad, fail
    character(len=*), intent(inout) :: buf
    integer(int64), intent(inout) :: t0
    call blocks_enter()
    call tic_master(t0)
    call shape_compute(s%g, s%p, s%sh, bad, fail, st)
    if (.not. all_ok(st)) return
    if (all_int(bad) /= 0) then
      !$omp single
      write (buf, '(a,i0,a)') 'step ', s%steps + 1, ': '
      call refuse_shape(s, bad, fail, trim(buf)//' ', 'has left the grid', st)
      !$omp end single
      return
    end if
    call strips_build(s%sp, s%sh%row, s%sh%span)
    !$omp single
    call node_range(s)
    !$omp end single
    call toc_master(s, TIMER_SHAPE, t0)
    if (proj) then   ! the operator of this step's configuration, for both projections
      call projection_setup(s%proj, s%opt%projection, s%opt%shape, s%g, s%p, s%pmask, st, s%sp)
      call toc_master(s, TIMER_PROJECTION, t0)
      if (.not. all_ok(st)) return
    end if

    call p2g(s)
    call toc_master(s, TIMER_P2G, t0)
    call grid_update(s, dt)
    call toc_master(s, TIMER_GRID, t0)
    call g2p(s, dt)
    call toc_master(s, TIMER_G2P, t0)
    call deformation_update(s, dt, st)
    call toc_master(s, TIMER_DEFORMATION, t0)
    if (.not. all_ok(st)) return
    if (proj) then
      call projection_apply(s%proj, s%opt%shape, s%g, s%p, s%pmask, s%p%work(1, :), st, s%sp)
      call toc_master(s, TIMER_PROJECTION, t0)
      if (.not. all_ok(st)) return
      call projected_deformation(s)
      call toc_master(s, TIMER_DEFORMATION, t0)
    end if
    !$omp single
    s%dt_last = dt
    !$omp end single
    call stress_update(s, st)
    call toc_master(s, TIMER_STRESS, t0)
    if (.not. all_ok(st)) return
    if (proj) then
      call project_mean_stress(s, st)
      call toc_master(s, TIMER_PROJECTION, t0)
    end if
  end subroutine step_phases

  integer function team_for_step(s, nthr) result(team)
    !! Which team runs this step: 1 (one thread) or 2 (nthr threads); 0 when there is no
    !! choice (nthr = 1). Threads never make a step slower: the wall time of a step is kept for
    !! both team sizes (an average over the last steps), the faster one runs, and a step now
    !! and then runs on the other to keep its time current: PROBE_MIN steps after the faster
    !! team changed, and each probe that confirms the choice doubles the gap, up to PROBE_MAX (probe_cap)
    !! (a probe costs a slow step). Beside a busy process a waiting thread's spin holds a core
    !! its partner needs, and 2 threads can take longer than 1; on an idle machine they are
    !! faster (measurements: docs/notes/threads.md). Results do not depend on the team (bitwise,
    !! cpdi_schedule).
    type(sim_t), intent(inout) :: s
    integer, intent(in) :: nthr
    team = 0
    if (nthr <= 1) return
    s%since_probe = s%since_probe + 1
    if (s%step_s(2) <= 0.0_wp) then   ! calibration: a first step on all threads (they start), a second
      team = 2
      if (s%step_s(2) == 0.0_wp) s%step_s(2) = -1.0_wp   ! (discarded), then one on 1 thread
    else if (s%step_s(1) == 0.0_wp) then
      team = 1
    else
      team = merge(1, 2, s%step_s(1) < s%step_s(2))
      if (team /= s%team) then   ! the faster team changed: probe the other one soon
        s%team = team
        s%probe_gap = PROBE_MIN
      end if
      if (s%since_probe >= s%probe_gap) then
        team = -(3 - team)   ! a probe of the other team: its time replaces the average
        s%since_probe = 0
      end if
    end if
  end function team_for_step

  subroutine team_measured(s, team, secs)
    !! Fold the wall time of a step run by team (1 or 2) into its average (weight 1/4 for
    !! the newest: a load that starts or stops shows within a few steps); a probe (-1, -2)
    !! replaces it, and doubles the gap to the next probe if the running team stays the
    !! faster (else the gap returns to PROBE_MIN). step_s(2) is -1 before the first step on
    !! all threads, -2 after it.
    type(sim_t), intent(inout) :: s
    integer, intent(in) :: team
    real(wp), intent(in) :: secs
    if (team < 0) then   ! a probe of team -team; the running team is 3 + team
      s%step_s(-team) = secs
      if (secs >= s%step_s(3 + team)) then
        s%probe_gap = min(2*s%probe_gap, probe_cap(secs, s%step_s(3 + team)))
      else
        s%probe_gap = PROBE_MIN
      end if
    else if (s%step_s(team) == -1.0_wp) then   ! the first step on all threads: threads start
      s%step_s(team) = -2.0_wp
    else if (s%step_s(team) <= 0.0_wp) then
      s%step_s(team) = secs
    else
      s%step_s(team) = 0.75_wp*s%step_s(team) + 0.25_wp*secs
    end if
  end subroutine team_measured

  pure integer(ik) function probe_cap(slow, fast)
    !! Longest gap between probes of a team that takes slow s a step, the running one fast s:
    !! PROBE_MAX, or PROBE_COST (slow / fast - 1) steps if longer (a probe then costs at most
    !! about 1 / PROBE_COST of the steps between two probes).
    real(wp), intent(in) :: slow, fast
    probe_cap = PROBE_MAX
    if (fast > 0.0_wp) probe_cap = max(PROBE_MAX, int(min(1.0e6_wp, real(PROBE_COST, wp)*(slow/fast - 1.0_wp)), ik))
  end function probe_cap

  subroutine advance_clock(s, dt)
    !! The clock and step counter after a step of dt.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    s%t = s%t + dt
    s%steps = s%steps + 1
    s%diag(DIAG_T) = s%t
    s%diag(DIAG_DT) = dt
    s%diag(DIAG_STEPS) = real(s%steps, wp)
  end subroutine advance_clock
end module cpdi_step
