!> The grid stage of the explicit step.
module cpdi_grid_update
  !! The grid stage of the explicit step: the nodes a step touches, nodal momenta to velocities, forces
  !! (with Cundall damping), rigid nodes, walls and Bardenhagen contact, field by field.
  !! Part of the explicit step (cpdi_step holds the sequence); OpenMP as described there.
  use cpdi_kinds, only: wp, ik
  use cpdi_grid, only: grid_t, grid_apply_walls
  use cpdi_contact, only: contact_correct
  use cpdi_sim, only: sim_t
  implicit none
  private

  public :: node_range, grid_update, momentum_to_velocity, impose_rigid

contains

  subroutine node_range(s)
    !! The nodes a step has to clear and update: the node rows this step's stencils span,
    !! joined with the last step's. Every grid array is zero outside the rows of the last
    !! step's stencils, so whole-grid loops over s%kw give the same values as over the grid.
    type(sim_t), intent(inout) :: s
    integer(ik) :: kn(2), nn1
    nn1 = s%g%nn(1)
    kn(1) = s%sp%rlo*nn1 + 1
    kn(2) = min((s%sp%rhi + s%sh%span + 1)*nn1, s%g%nnodes)
    s%kw = [max(1_ik, min(kn(1), s%kprev(1))), min(s%g%nnodes, max(kn(2), s%kprev(2)))]
    s%kprev = kn
  end subroutine node_range

  subroutine grid_update(s, dt)
    !! Nodal velocities at t^n (stored back in px, py) and t^{n+1} (vx, vy), per field;
    !! rigid nodes, walls, and (with several fields) contact at both stages.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik) :: k, f
    real(wp) :: rm, fx, fy, alpha

    alpha = s%opt%damping
    associate (g => s%g)
      call momentum_to_velocity(g, s%mtol, s%kw, g%px, g%py)
      if (s%any_rigid) then
        !$omp single
        call impose_rigid(g, s%kw, g%px, g%py)
        !$omp end single
      end if
      ! Contact corrects the integrated velocity only: the FLIP increment v^{n+1} - v^n then
      ! carries the whole contact impulse to the particles (a correction of v^n would be lost
      ! to them and let approaching bodies keep kinetic energy the grid no longer has).
      do f = 1, g%nf
        !$omp do schedule(static) private(k, rm, fx, fy)
        do k = s%kw(1), s%kw(2)
          if (g%m(k, f) > s%mtol) then
            rm = 1.0_wp/g%m(k, f)
            fx = g%fx(k, f)
            fy = g%fy(k, f)
            if (alpha > 0.0_wp) then
              fx = fx - alpha*abs(fx)*sign(1.0_wp, g%px(k, f))
              fy = fy - alpha*abs(fy)*sign(1.0_wp, g%py(k, f))
            end if
            g%vx(k, f) = g%px(k, f) + dt*fx*rm
            g%vy(k, f) = g%py(k, f) + dt*fy*rm
          else
            g%vx(k, f) = 0.0_wp
            g%vy(k, f) = 0.0_wp
          end if
        end do
        !$omp end do
      end do
      !$omp single
      if (s%any_rigid) call impose_rigid(g, s%kw, g%vx, g%vy)
      do f = 1, g%nf
        call walls_of_field(s, f, g%px(:, f), g%py(:, f))
        call walls_of_field(s, f, g%vx(:, f), g%vy(:, f))
      end do
      if (g%nf > 1) then
        call contact_correct(g, s%kw, g%vx, g%vy, s%mtol, s%friction, s%fullness*g%h**2, s%field_rigid, s%diag(13))
        do f = 1, g%nf
          call walls_of_field(s, f, g%vx(:, f), g%vy(:, f))
        end do
      end if
      !$omp end single
    end associate
  end subroutine grid_update

  subroutine walls_of_field(s, f, vx, vy)
    !! Wall conditions on field f. With contact, walls meet solid bodies under the bodies'
    !! volume constraint (a stiff body lands on the floor, not a cell above it: see
    !! grid_apply_walls); fluids, and every run without contact, are held wherever they
    !! reach a wall node.
    type(sim_t), intent(in) :: s
    integer(ik), intent(in) :: f
    real(wp), intent(inout) :: vx(:), vy(:)
    if (s%field_solid(f)) then
      call grid_apply_walls(s%g, vx, vy, s%g%gv(:, f), s%fullness*s%g%h**2)
    else
      call grid_apply_walls(s%g, vx, vy)
    end if
  end subroutine walls_of_field

  subroutine momentum_to_velocity(g, mtol, kw, qx, qy)
    !! In place: nodal momentum (qx, qy) of every field -> velocity q/m on nodes kw(1)..kw(2);
    !! nodes lighter than mtol carry no velocity.
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: mtol
    integer(ik), intent(in) :: kw(2)
    real(wp), intent(inout) :: qx(:, :), qy(:, :)
    integer(ik) :: k, f
    real(wp) :: rm
    do f = 1, g%nf
      !$omp do schedule(static) private(k, rm)
      do k = kw(1), kw(2)
        if (g%m(k, f) > mtol) then
          rm = 1.0_wp/g%m(k, f)
          qx(k, f) = qx(k, f)*rm
          qy(k, f) = qy(k, f)*rm
        else
          qx(k, f) = 0.0_wp
          qy(k, f) = 0.0_wp
        end if
      end do
      !$omp end do
    end do
  end subroutine momentum_to_velocity

  subroutine impose_rigid(g, kw, vx, vy)
    !! Nodes touched by rigid particles move with them (clamped body), field by field, on nodes
    !! kw(1)..kw(2) (the rigid mass mr is zero outside them).
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: kw(2)
    real(wp), intent(inout) :: vx(:, :), vy(:, :)
    integer(ik) :: k, f
    do f = 1, g%nf
      do k = kw(1), kw(2)
        if (g%mr(k, f) > 0.0_wp) then
          vx(k, f) = g%prx(k, f)/g%mr(k, f)
          vy(k, f) = g%pry(k, f)/g%mr(k, f)
        end if
      end do
    end do
  end subroutine impose_rigid
end module cpdi_grid_update
