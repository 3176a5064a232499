!> Solids coupled to the incompressible water through face fractions and boundary fluxes
!> (after Batty, Bertails & Bridson 2007; docs/fsi_incompressible.md, 'Deformable solids, coupling = "batty"').
module cpdi_coupling
  !! The pressure lives in the water's cells only; the solid enters each cell's constraint as the
  !! flux of its boundary through it. With w_f = V_s,f / h^2 (clamped to [0, 1]) the solid fraction
  !! of face f, m_f and u_s,f the solid's face mass and velocity, u_f the water's:
  !!
  !! * phi_c = (1/4) sum_{f in faces(c)} w_f. Water cells (cpl_classify) from the water's and the
  !!   solid's cell fills f_w, f_s (both spread bilinearly from the particles alike): cells the
  !!   solid fills less than half by f_w >= FILL_MIN and f_w + f_s >= 1/2, then the cells it fills
  !!   more than half next to those across its boundary. Every other cell is air (p = 0), the
  !!   solid's inside too. (The survey's rule f_w >= (1 - phi) / 2 is not used: phi, from the faces'
  !!   control volumes, is blurred unlike f_w (f_w + phi - 1 is -1/16 to +1/16 along a resting
  !!   block's faces, f_w + f_s - 1 is 0), and a void a moving block leaves is under-filled water,
  !!   not air.)
  !! * C_c = h [ sum_f sigma_f (1 - w_f) u_f + g^x_c ubar^x_c + g^y_c ubar^y_c ], sigma = +1 on the
  !!   right and top faces, g^x_c = w(right) - w(left), ubar^x_c = the solid's velocity over the two
  !!   x faces, weighted by their solid mass (y alike): u . grad chi of the solid's indicator, its
  !!   boundary's flux without its own dilatation (which its elasticity governs).
  !! * Minimising the kinetic energy (water face mass rho h^2 (1 - w_f), solid face mass m_f)
  !!   under C = 0: M du = dt C^T p and (rho / dt) dt C M^-1 C^T p = -(rho / dt) C(u*), a 5-point
  !!   symmetric system in the existing storage (adiag, ai, aj; b), scaled as the water-only one
  !!   (water faces enter with weight 1 - w_f; the ghost-fluid surface divides by theta):
  !!     water face:  du_f = (dt / (rho h)) (p_L - p_R) (mac_project with coefficient 1)
  !!     solid face:  I_f = dt h m_f sum_{c next to f, water} p_c g_c / M_c, M_c the solid mass of
  !!                  c's two faces along f's axis.
  !!   A uniform p gives no net force (sum_c g_c telescopes); a hydrostatic p gives exactly
  !!   rho g sum_f w_f h^2 upwards (Archimedes on the face volumes).
  !! Faces touching a wall or a rigid body's cell (CELL_SOLID) are not free: their velocities are
  !! the wall's, they receive no impulse.
  use cpdi_kinds, only: wp, ik
  use cpdi_pressure, only: mac_t, surface_theta, mac_clear_system, CELL_FLUID, CELL_AIR, CELL_SOLID
  implicit none
  private

  real(wp), parameter :: FILL_MIN = 0.05_wp   !! least water fill of a water cell next to a solid
  real(wp), parameter :: G_MIN = 0.1_wp        !! least solid boundary (|g|) along a face the water extends across
  real(wp), parameter :: W_FULL = 0.9_wp       !! a face more solid than this is solid (w = 1): no water DOF of tiny mass
  real(wp), parameter :: PHI_MAX = 0.99_wp     !! cells more solid than this are the solid's inside (air)
  real(wp), parameter :: DIAG_MIN = 1.0e-6_wp  !! a water cell whose weights sum below this is decoupled (p = 0)

  public :: cpl_fractions, cpl_classify, cpl_close, cpl_constraint, cpl_assemble, cpl_impulse

contains

  subroutine cpl_fractions(mc, uvs, vvs, wu, wv, phi)
    !! Solid fractions of the faces (wu, wv) and cells (phi; 0 outside the physical cells). A face
    !! filled beyond W_FULL is full: its water share would be a degree of freedom of tiny mass,
    !! which the energy minimisation drives fast (jets of 2-3 m/s along a sinking block's sides
    !! inside its edge cells, and a burst of kinetic energy).
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: uvs(:), vvs(:)
    real(wp), intent(inout) :: wu(:), wv(:), phi(:)
    integer(ik) :: i, j, c, n1
    real(wp) :: a
    n1 = mc%nn(1)
    a = 1.0_wp/mc%h**2
    wu = min(max(uvs*a, 0.0_wp), 1.0_wp)
    wv = min(max(vvs*a, 0.0_wp), 1.0_wp)
    where (wu > W_FULL) wu = 1.0_wp
    where (wv > W_FULL) wv = 1.0_wp
    phi = 0.0_wp
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        phi(c) = 0.25_wp*(wu(c) + wu(c + 1) + wv(c) + wv(c + n1))
      end do
    end do
  end subroutine cpl_fractions

  subroutine cpl_classify(mc, fillw, phi, wu, wv, sfill)
    !! Water cells from the water's own fill. On entry mc%cell marks the cells holding a water
    !! particle's centre (and walls, rigid cells) and mc%fill is the cell fill of all particles; on
    !! exit sfill = the solid's fill (mc%fill - fillw) and, with phi < PHI_MAX throughout (beyond
    !! it the solid's inside, where stray water would make a pocket of water cells with no free
    !! face):
    !! 1. a cell the solid fills less than half is water if fillw >= FILL_MIN and water and solid
    !!    fill it to 1/2 or more (a void left behind a moving solid is under-filled water, which the
    !!    volume correction fills, not air: air there let the water above a sinking block fall into
    !!    it at g); with phi = 0 the water-only rule (a water particle's centre, or fillw > 1/2);
    !! 2. a cell the solid fills half or more is water if it shares a face open to water (w_f < 1)
    !!    with a cell of 1., along an axis on which the solid's boundary crosses it (|g| > G_MIN):
    !!    the water reaches into the solid by a cell, as Batty et al.'s level set does, and the
    !!    pressure on that boundary acts on it (a block's bottom row, left air as the block sank out
    !!    of it, put the water's faces under it at p = 0 and sucked the water up). Not from water
    !!    it touches through another solid cell, nor from stray water: a splash on an entering
    !!    block's top corner made its edge cell water surrounded by air, whose constraint pulled in
    !!    water at 10-30 m/s (-157 kPa) as the block moved away from it; nor a floating block's edge
    !!    column above its waterline (no boundary across the face to the water below).
    !! Every other cell is air (p = 0). mc%fill (all particles) places the ghost-fluid surface.
    !! A face between a water cell and a cell of air the solid fills half or more is closed
    !! (w_f = 1): the water there touches the solid, not air (p = 0 across it drove the water
    !! trapped under a landed block into the cells under it at 10-15 m/s).
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: fillw(:), phi(:)
    real(wp), intent(inout) :: wu(:), wv(:)
    real(wp), intent(inout) :: sfill(:)
    integer(ik), parameter :: EXTENDED = -1
    integer(ik) :: i, j, c, n1
    logical :: centre, gx, gy
    n1 = mc%nn(1)
    sfill = 0.0_wp   ! also beyond the physical cells: closed() reads it past an open side
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) == CELL_SOLID) cycle
        centre = mc%cell(c) == CELL_FLUID
        sfill(c) = max(mc%fill(c) - fillw(c), 0.0_wp)
        if (phi(c) < PHI_MAX .and. sfill(c) < 0.5_wp .and. &
            ((mc%fill(c) >= 0.5_wp .and. fillw(c) >= FILL_MIN) .or. &
             (phi(c) == 0.0_wp .and. (centre .or. fillw(c) > 0.5_wp)))) then
          mc%cell(c) = CELL_FLUID
        else
          mc%cell(c) = CELL_AIR
        end if
      end do
    end do
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_AIR .or. .not. (phi(c) < PHI_MAX .and. sfill(c) >= 0.5_wp)) cycle
        gx = abs(wu(c + 1) - wu(c)) > G_MIN
        gy = abs(wv(c + n1) - wv(c)) > G_MIN
        if ((gx .and. mc%cell(c - 1) == CELL_FLUID .and. wu(c) < 1.0_wp) .or. &
            (gx .and. mc%cell(c + 1) == CELL_FLUID .and. wu(c + 1) < 1.0_wp) .or. &
            (gy .and. mc%cell(c - n1) == CELL_FLUID .and. wv(c) < 1.0_wp) .or. &
            (gy .and. mc%cell(c + n1) == CELL_FLUID .and. wv(c + n1) < 1.0_wp)) mc%cell(c) = EXTENDED
      end do
    end do
    where (mc%cell == EXTENDED) mc%cell = CELL_FLUID
    call cpl_close(mc, wu, wv, sfill)
  end subroutine cpl_classify

  subroutine cpl_close(mc, wu, wv, sfill)
    !! A face between a water cell and a cell of air the solid fills half or more (sfill >= 1/2) is
    !! closed (w_f = 1): the water there touches the solid, not air.
    type(mac_t), intent(in) :: mc
    real(wp), intent(inout) :: wu(:), wv(:)
    real(wp), intent(in) :: sfill(:)
    integer(ik) :: i, j, c, n1
    n1 = mc%nn(1)
    do j = mc%lo(2), mc%hi(2) + 1
      do i = mc%lo(1), mc%hi(1) + 1
        c = i + (j - 1)*n1
        if (closed(c - 1, c)) wu(c) = 1.0_wp
        if (closed(c - n1, c)) wv(c) = 1.0_wp
      end do
    end do
  contains
    logical function closed(cl, cr)
      integer(ik), intent(in) :: cl, cr
      closed = (mc%cell(cl) == CELL_FLUID .and. mc%cell(cr) == CELL_AIR .and. sfill(cr) >= 0.5_wp) .or. &
               (mc%cell(cr) == CELL_FLUID .and. mc%cell(cl) == CELL_AIR .and. sfill(cl) >= 0.5_wp)
    end function closed
  end subroutine cpl_close

  pure logical function free(mc, cl, cr)
    !! A face between cells cl and cr is free unless one of them is a wall or rigid body.
    type(mac_t), intent(in) :: mc
    integer(ik), intent(in) :: cl, cr
    free = mc%cell(cl) /= CELL_SOLID .and. mc%cell(cr) /= CELL_SOLID
  end function free

  subroutine cpl_constraint(mc, u, v, wu, wv, usm, vsm, us, vs, mtol, solid, cflux)
    !! cflux = C_c(u, v; us, vs) [m^2/s] in every water cell (0 elsewhere); solid = .false.: the
    !! water's term alone (the solid held still).
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: u(:), v(:), wu(:), wv(:), usm(:), vsm(:), us(:), vs(:), mtol
    logical, intent(in) :: solid
    real(wp), intent(inout) :: cflux(:)
    integer(ik) :: i, j, c, n1
    n1 = mc%nn(1)
    cflux = 0.0_wp
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) cycle
        cflux(c) = cell_flux(mc, c, u, v, wu, wv, usm, vsm, us, vs, mtol, solid)
      end do
    end do
  end subroutine cpl_constraint

  pure real(wp) function cell_flux(mc, c, u, v, wu, wv, usm, vsm, us, vs, mtol, solid) result(cf)
    type(mac_t), intent(in) :: mc
    integer(ik), intent(in) :: c
    real(wp), intent(in) :: u(:), v(:), wu(:), wv(:), usm(:), vsm(:), us(:), vs(:), mtol
    logical, intent(in) :: solid
    integer(ik) :: n1
    real(wp) :: mx
    n1 = mc%nn(1)
    cf = (1.0_wp - wu(c + 1))*u(c + 1) - (1.0_wp - wu(c))*u(c) + (1.0_wp - wv(c + n1))*v(c + n1) &
         - (1.0_wp - wv(c))*v(c)
    if (solid) then
      mx = usm(c) + usm(c + 1)
      if (mx > mtol) cf = cf + (wu(c + 1) - wu(c))*(usm(c)*us(c) + usm(c + 1)*us(c + 1))/mx
      mx = vsm(c) + vsm(c + n1)
      if (mx > mtol) cf = cf + (wv(c + n1) - wv(c))*(vsm(c)*vs(c) + vsm(c + n1)*vs(c + n1))/mx
    end if
    cf = cf*mc%h
  end function cell_flux

  subroutine cpl_assemble(mc, dt, rho, wu, wv, usm, vsm, us, vs, mtol, solid, beta, fillw, sfill)
    !! Matrix and right-hand side (rho / dt)(h^2 q - C(u*)) of the coupled pressure equation on the
    !! water cells (scaled as mac_assemble: water faces of weight 1 - w_f). solid = .false.: the
    !! water's part only, the solid held still (the volume correction's system). With beta > 0
    !! (and fillw, sfill) the target q = beta clamp(fillw + sfill - 1, -1/2, 1/2) / dt: two-sided
    !! in cells with no air neighbour, over-filling only next to air.
    type(mac_t), intent(inout) :: mc
    real(wp), intent(in) :: dt, rho, mtol, beta
    real(wp), intent(in) :: wu(:), wv(:), usm(:), vsm(:), us(:), vs(:)
    logical, intent(in) :: solid
    real(wp), intent(in), optional :: fillw(:), sfill(:)
    integer(ik) :: i, j, c, n1, nb(4), a
    real(wp) :: af(4), rh2, g, gn, mx, mxn, sx, qv, e
    logical :: air
    n1 = mc%nn(1)
    rh2 = rho*mc%h**2
    call mac_clear_system(mc)
    do j = mc%lo(2), mc%hi(2)
      do i = mc%lo(1), mc%hi(1)
        c = i + (j - 1)*n1
        if (mc%cell(c) /= CELL_FLUID) cycle
        mc%nfluid = mc%nfluid + 1
        nb = [c - 1, c + 1, c - n1, c + n1]
        af = [1.0_wp - wu(c), 1.0_wp - wu(c + 1), 1.0_wp - wv(c), 1.0_wp - wv(c + n1)]
        air = .false.
        do a = 1, 4
          select case (mc%cell(nb(a)))
          case (CELL_FLUID)
            mc%adiag(c) = mc%adiag(c) + af(a)
            if (a == 2) mc%ai(c) = -af(a)
            if (a == 4) mc%aj(c) = -af(a)
          case (CELL_AIR)
            mc%adiag(c) = mc%adiag(c) + af(a)/surface_theta(mc, mc%fill(c), mc%fill(nb(a)))
            if (af(a) > 0.0_wp) air = .true.
          end select
        end do
        if (solid) then
          ! x: faces c (left) and c + 1 (right); the right neighbour shares face c + 1
          g = wu(c + 1) - wu(c)
          mx = usm(c) + usm(c + 1)
          if (g /= 0.0_wp .and. mx > mtol) then
            sx = 0.0_wp
            if (usm(c) > mtol .and. free(mc, c - 1, c)) sx = sx + usm(c)
            if (usm(c + 1) > mtol .and. free(mc, c, c + 1)) sx = sx + usm(c + 1)
            mc%adiag(c) = mc%adiag(c) + rh2*g*g*sx/mx**2
            if (mc%cell(c + 1) == CELL_FLUID .and. usm(c + 1) > mtol) then
              gn = wu(c + 2) - wu(c + 1)
              mxn = usm(c + 1) + usm(c + 2)
              mc%ai(c) = mc%ai(c) + rh2*g*gn*usm(c + 1)/(mx*mxn)
            end if
          end if
          g = wv(c + n1) - wv(c)
          mx = vsm(c) + vsm(c + n1)
          if (g /= 0.0_wp .and. mx > mtol) then
            sx = 0.0_wp
            if (vsm(c) > mtol .and. free(mc, c - n1, c)) sx = sx + vsm(c)
            if (vsm(c + n1) > mtol .and. free(mc, c, c + n1)) sx = sx + vsm(c + n1)
            mc%adiag(c) = mc%adiag(c) + rh2*g*g*sx/mx**2
            if (mc%cell(c + n1) == CELL_FLUID .and. vsm(c + n1) > mtol) then
              gn = wv(c + 2*n1) - wv(c + n1)
              mxn = vsm(c + n1) + vsm(c + 2*n1)
              mc%aj(c) = mc%aj(c) + rh2*g*gn*vsm(c + n1)/(mx*mxn)
            end if
          end if
        end if
        qv = 0.0_wp
        if (beta > 0.0_wp .and. present(fillw) .and. present(sfill)) then
          e = min(max(fillw(c) + sfill(c) - 1.0_wp, -0.5_wp), 0.5_wp)
          if (air) e = max(e, 0.0_wp)
          qv = beta*e/dt
        end if
        mc%b(c) = (rho/dt)*(mc%h**2*qv - cell_flux(mc, c, mc%u, mc%v, wu, wv, usm, vsm, us, vs, mtol, solid))
        if (.not. (mc%adiag(c) > DIAG_MIN)) then   ! (almost) no free face: decoupled, p = 0
          mc%adiag(c) = 1.0_wp
          mc%b(c) = 0.0_wp
        end if
      end do
    end do
  end subroutine cpl_assemble

  subroutine cpl_impulse(mc, dt, wu, wv, usm, vsm, mtol, iu, iv)
    !! Impulse of the pressure (mc%p) on every free solid face [N s / m]:
    !! I_f = dt h m_f sum_{c next to f, water} p_c g_c / M_c.
    type(mac_t), intent(in) :: mc
    real(wp), intent(in) :: dt, wu(:), wv(:), usm(:), vsm(:), mtol
    real(wp), intent(inout) :: iu(:), iv(:)
    integer(ik) :: i, j, k, n1
    real(wp) :: s
    n1 = mc%nn(1)
    iu = 0.0_wp
    iv = 0.0_wp
    do j = 2, mc%nn(2) - 2
      do i = 2, n1 - 2
        k = i + (j - 1)*n1
        if (usm(k) > mtol .and. free(mc, k - 1, k)) then   ! u face k: cells k - 1 (its right face) and k
          s = 0.0_wp
          if (mc%cell(k - 1) == CELL_FLUID) s = s + mc%p(k - 1)*cterm(wu(k) - wu(k - 1), usm(k - 1) + usm(k))
          if (mc%cell(k) == CELL_FLUID) s = s + mc%p(k)*cterm(wu(k + 1) - wu(k), usm(k) + usm(k + 1))
          iu(k) = dt*mc%h*usm(k)*s
        end if
        if (vsm(k) > mtol .and. free(mc, k - n1, k)) then   ! v face k: cells k - n1 (its top face) and k
          s = 0.0_wp
          if (mc%cell(k - n1) == CELL_FLUID) s = s + mc%p(k - n1)*cterm(wv(k) - wv(k - n1), vsm(k - n1) + vsm(k))
          if (mc%cell(k) == CELL_FLUID) s = s + mc%p(k)*cterm(wv(k + n1) - wv(k), vsm(k) + vsm(k + n1))
          iv(k) = dt*mc%h*vsm(k)*s
        end if
      end do
    end do
  contains
    pure real(wp) function cterm(g, m)
      real(wp), intent(in) :: g, m
      cterm = 0.0_wp
      if (m > mtol) cterm = g/m
    end function cterm
  end subroutine cpl_impulse
end module cpdi_coupling
