!> Multi-velocity-field frictional contact (Bardenhagen et al. 2000; FORMULAS 6).
module cpdi_contact
  !! Each body carries its own grid velocity field. At a node where two or more fields
  !! have mass, field b is compared with the centre-of-mass velocity v_cm (or with a rigid
  !! body's prescribed velocity, which acts as an infinite mass). With
  !! q_b = sum_p m_p grad S_ip (the P2G mass gradient; it differentiates with respect to
  !! the particle position, so it is MINUS the gradient of the nodal mass field and points
  !! out of the body) the outward normal is n_b = (q_b - sum_{c /= b} q_c) / |.|, so for two
  !! bodies n_1 = -n_2 and the correction conserves momentum exactly. Against a rigid body
  !! the normal is minus the rigid body's outward normal. Contact is active when field b approaches,
  !! dv_n = (v_b - v_cm) . n_b > 0; a body pressed against another by its stress or by
  !! gravity approaches at every step of the explicit update, so this test also holds
  !! bodies in compression, and separating bodies are left free. The correction is
  !!   dv_c = -dv_n n - mu' dv_n t,   mu' = min(mu, |dv_t| / dv_n)   (Coulomb: stick if mu' < mu)
  !! and the frictional work m_b mu' dv_n (|dv_t| - mu' dv_n) is accumulated when slipping.
  !! The step applies it to the integrated velocity v^{n+1}, so the particles' FLIP
  !! increment carries the contact impulse. Volume constraint (Bardenhagen et al. 2001): a
  !! node is in contact only when the bodies' volumes fill its support,
  !! sum_b V_i^b >= vfull (= fullness h^2) times the fraction of the node's hat function that
  !! lies inside the domain (a node on a wall can only ever be half full); bodies sharing a
  !! node across a gap do not touch.
  use cpdi_kinds, only: wp, ik
  use cpdi_grid, only: grid_t, inside_fraction
  implicit none
  private

  public :: contact_correct

contains

  subroutine contact_correct(g, kw, vx, vy, mtol, mu, vfull, rigidf, work)
    !! Correct the field velocities vx, vy (node, field) in place on nodes kw(1)..kw(2) (no
    !! field has mass outside them); add frictional work to `work`.
    type(grid_t), intent(in) :: g
    integer(ik), intent(in) :: kw(2)
    real(wp), intent(inout) :: vx(:, :), vy(:, :)
    real(wp), intent(in) :: mtol, mu, vfull
    logical, intent(in) :: rigidf(:)
    real(wp), intent(inout) :: work
    integer(ik) :: k, f, nfm, frig
    real(wp) :: msum, vcm(2), gs(2), nrm(2), nn, dv(2), dvn, dvt(2), tn, mup, dc(2), vsum

    do k = kw(1), kw(2)
      nfm = 0
      msum = 0.0_wp
      vcm = 0.0_wp
      gs = 0.0_wp
      frig = 0
      vsum = 0.0_wp
      do f = 1, g%nf
        vsum = vsum + g%gv(k, f)
        if (g%m(k, f) > mtol) then
          nfm = nfm + 1
          msum = msum + g%m(k, f)
          vcm = vcm + g%m(k, f)*[vx(k, f), vy(k, f)]
          if (rigidf(f)) frig = f
        end if
        gs = gs + [g%gmx(k, f), g%gmy(k, f)]
      end do
      if (nfm < 2) cycle
      if (vsum < vfull*inside_fraction(g, k)) cycle
      if (frig > 0) then
        vcm = [vx(k, frig), vy(k, frig)]
      else
        vcm = vcm/msum
      end if
      do f = 1, g%nf
        if (.not. (g%m(k, f) > mtol) .or. rigidf(f)) cycle
        if (frig > 0) then
          ! against a rigid body its own surface normal is the reliable one (a deformable
          ! body's normal tilts at its corners and would brake tangential sliding)
          nrm = -[g%gmx(k, frig), g%gmy(k, frig)]
        else
          nrm = 2.0_wp*[g%gmx(k, f), g%gmy(k, f)] - gs
        end if
        nn = norm2(nrm)
        if (.not. (nn > 0.0_wp)) cycle
        nrm = nrm/nn
        dv = [vx(k, f), vy(k, f)] - vcm
        dvn = dot_product(dv, nrm)
        if (.not. (dvn > 0.0_wp)) cycle
        dvt = dv - dvn*nrm
        tn = norm2(dvt)
        if (tn > 1.0e-14_wp*norm2(dv)) then
          mup = min(mu, tn/dvn)
          dc = -dvn*nrm - mup*dvn*dvt/tn
          work = work + g%m(k, f)*mup*dvn*(tn - mup*dvn)
        else
          dc = -dvn*nrm
        end if
        vx(k, f) = vx(k, f) + dc(1)
        vy(k, f) = vy(k, f) + dc(2)
      end do
    end do
  end subroutine contact_correct
end module cpdi_contact
