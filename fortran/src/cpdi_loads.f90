!> The water's load on the solids of a coupled step: a force and a couple per solid particle.
module cpdi_loads
  !! After a coupled step (cpdi_fsi) every solid particle carries the incompressible water's load
  !! of that step, wl(:, ip) = [fx, fy, c]: a force [N/m] and a couple about the particle's centre
  !! [N m/m], so that the moment about any point O of a set of particles is
  !! sum (x_p - O) x f_p + c_p. Summed over a body's particles they give the water's force and
  !! moment on the body, whatever kind it is:
  !!
  !! * a deformable solid: its particles' momentum change by the projection over dt (cpdi_fsi
  !!   solid_g2p), acting at the particles (c = 0);
  !! * a free rigid body: the force and torque J^T p of the boundary-flux operator
  !!   (cpdi_rigid_body), shared by the particles in proportion to their mass;
  !! * a prescribed `rigid` body: its cells bound the water (CELL_SOLID), and the water pushes on
  !!   every face between one of its cells and a water cell with the face's pressure, p_f h. p_f
  !!   is extrapolated linearly from the two water cells along the face's normal (the second one
  !!   an air cell: its ghost-fluid value; a wall or a solid: the hydrostatic gradient rho g from
  !!   the first), exact for a hydrostatic pressure. A cell's faces go to the body's particles in
  !!   it in proportion to their mass, with the couple of their lever arms: the body feels the
  !!   pressure on its staircase of cells, which a cell-aligned body fills exactly.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_ALLOC
  use cpdi_particles, only: particles_t
  use cpdi_grid, only: grid_t
  use cpdi_pressure, only: mac_t, surface_theta, CELL_FLUID, CELL_AIR
  use cpdi_rigid_body, only: rbody_t
  implicit none
  private

  type, public :: loads_t
    !! The loads of the last coupled step and the work storage of the prescribed bodies' faces.
    real(wp), allocatable :: wl(:, :)     !! (3, n): per particle, force [N/m] and couple [N m/m]
    real(wp), allocatable :: cell(:, :)   !! (4, cells): rigid mass, force x, y, couple about the centre
  end type loads_t

  public :: loads_prepare, loads_rigid, loads_free

contains

  subroutine loads_prepare(ld, n, ncells, st)
    !! Storage for n particles and a lattice of ncells cells; the loads start at zero.
    type(loads_t), intent(inout) :: ld
    integer(ik), intent(in) :: n, ncells
    type(status_t), intent(inout) :: st
    integer(ik) :: ierr
    logical :: realloc
    realloc = .not. allocated(ld%wl)
    if (.not. realloc) realloc = size(ld%wl, 2) /= n .or. size(ld%cell, 2) /= ncells
    if (realloc) then
      if (allocated(ld%wl)) deallocate (ld%wl, ld%cell)
      allocate (ld%wl(3, n), ld%cell(4, ncells), stat=ierr)
      if (ierr /= 0) then
        call st%set(CPDI_ERR_ALLOC, 'could not allocate the water''s loads on the solids; use fewer particles')
        return
      end if
      ld%wl = 0.0_wp
      ld%cell = 0.0_wp
    end if
  end subroutine loads_prepare

  subroutine loads_rigid(ld, p, rigid, mc, g, rho, gravity)
    !! The loads on the particles of prescribed rigid bodies (rigid(m): material m is one) from
    !! the pressure of the step just solved (mc), before the particles move: each particle's cell
    !! is the one mark_rigid (cpdi_incompressible) made a CELL_SOLID cell with it.
    type(loads_t), intent(inout) :: ld
    type(particles_t), intent(in) :: p
    logical, intent(in) :: rigid(:)
    type(mac_t), intent(in) :: mc
    type(grid_t), intent(in) :: g
    real(wp), intent(in) :: rho, gravity(2)
    integer(ik) :: ip, k, i, j, n1, a, nb, nb2, step(4)
    real(wp) :: s(2), pf, f(2), e(2), xc(2), share, dirs(2, 4)
    n1 = mc%nn(1)
    step = [-1_ik, 1_ik, -n1, n1]
    dirs = reshape([-1.0_wp, 0.0_wp, 1.0_wp, 0.0_wp, 0.0_wp, -1.0_wp, 0.0_wp, 1.0_wp], [2, 4])
    ld%cell(1, :) = 0.0_wp
    do ip = 1, p%n
      if (.not. rigid(p%mat(ip))) cycle
      k = cell_of(p%x(:, ip))
      if (k > 0) ld%cell(1, k) = ld%cell(1, k) + p%m(ip)
    end do
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        k = i + (j - 1)*n1
        ld%cell(2:4, k) = 0.0_wp
        if (.not. (ld%cell(1, k) > 0.0_wp)) cycle
        do a = 1, 4
          nb = k + step(a)
          if (mc%cell(nb) /= CELL_FLUID) cycle
          nb2 = nb + step(a)
          e = dirs(:, a)   ! the body's outward normal on this face
          if (mc%cell(nb2) == CELL_FLUID) then
            pf = 1.5_wp*mc%p(nb) - 0.5_wp*mc%p(nb2)
          else if (mc%cell(nb2) == CELL_AIR) then   ! the ghost-fluid value across the surface
            pf = 1.5_wp*mc%p(nb) - 0.5_wp*mc%p(nb)*(1.0_wp - 1.0_wp/surface_theta(mc, mc%fill(nb), mc%fill(nb2)))
          else
            pf = mc%p(nb) - rho*0.5_wp*mc%h*dot_product(gravity, e)   ! half a cell towards the body (-e)
          end if
          f = -pf*mc%h*e
          ld%cell(2:3, k) = ld%cell(2:3, k) + f
          ld%cell(4, k) = ld%cell(4, k) + 0.5_wp*mc%h*(e(1)*f(2) - e(2)*f(1))   ! about the cell's centre
        end do
      end do
    end do
    do ip = 1, p%n
      if (.not. rigid(p%mat(ip))) cycle
      ld%wl(:, ip) = 0.0_wp
      k = cell_of(p%x(:, ip))
      if (k == 0) cycle
      share = p%m(ip)/ld%cell(1, k)
      xc = g%gorig + ([real(mod(k - 1, n1) + 1, wp), real((k - 1)/n1 + 1, wp)] - 0.5_wp)*g%h
      f = share*ld%cell(2:3, k)
      s = xc - p%x(:, ip)
      ld%wl(1:2, ip) = f
      ld%wl(3, ip) = share*ld%cell(4, k) + s(1)*f(2) - s(2)*f(1)
    end do
  contains
    integer(ik) function cell_of(x)
      !! The physical cell holding x (0: none), as mark_rigid finds it.
      real(wp), intent(in) :: x(2)
      integer(ik) :: ic, jc
      real(wp) :: q(2)
      q = (x - g%gorig)/g%h
      ic = int(q(1)) + 1
      jc = int(q(2)) + 1
      cell_of = 0
      if (ic >= mc%lo(1) .and. ic <= mc%hi(1) .and. jc >= mc%lo(2) .and. jc <= mc%hi(2)) cell_of = ic + (jc - 1)*n1
    end function cell_of
  end subroutine loads_rigid

  subroutine loads_free(ld, p, rb)
    !! The loads on the particles of free rigid bodies, after they moved: each particle takes its
    !! mass's share m_p / M of the body's force F (at the particle) and of its torque T (about the
    !! mass centre, as a couple): the body's particles give F and, about their mass centre, T.
    type(loads_t), intent(inout) :: ld
    type(particles_t), intent(in) :: p
    type(rbody_t), intent(in) :: rb
    integer(ik) :: ip, b
    real(wp) :: share, f(2)
    if (rb%n == 0) return
    do ip = 1, p%n
      b = rb%slot(ip)
      if (b == 0) cycle
      share = p%m(ip)/rb%m(b)
      f = share*rb%force(1:2, b)
      ld%wl(1:2, ip) = f
      ld%wl(3, ip) = share*rb%force(3, b)
    end do
  end subroutine loads_free
end module cpdi_loads
