!> Particle-grid transfers of the explicit step on the nodal grid.
module cpdi_transfer
  !! Particle-grid transfers of the explicit step on the nodal grid: P2G of mass, momentum and force
  !! (strip colour by colour), G2P (FLIP/PIC blend, positions, diagnostics) and the MUSL remap with
  !! the velocity gradient. (Incompressible water has its own, on the staggered grid:
  !! cpdi_incompressible.)
  !! Part of the explicit step (cpdi_step holds the sequence); OpenMP as described there.
  use cpdi_kinds, only: wp, ik
  use cpdi_grid, only: grid_apply_walls, grid_clear_p2g, grid_box, WALL_OPEN
  use cpdi_shape, only: shape_t
  use cpdi_schedule, only: NCHUNK, chunk_range, blocks_t, block_start, strip_start, block_next
  use cpdi_sim, only: sim_t, UPDATE_MUSL
  use cpdi_grid_update, only: momentum_to_velocity, impose_rigid
  implicit none
  private

  public :: p2g, g2p

contains

  subroutine p2g(s)
    !! Scatter mass, momentum and force to the nodes of each particle's velocity field
    !! (and the mass gradient, for contact normals, when there are several fields), strip
    !! colour by colour (cpdi_schedule).
    type(sim_t), intent(inout) :: s
    integer(ik) :: b, colour
    logical :: simple
    type(blocks_t) :: blk

    call grid_clear_p2g(s%g, s%kw(1), s%kw(2))
    ! The other sums P2G makes, on the same nodes (outside s%kw they are zero: cpdi_grid_update
    ! node_range).
    !$omp single
    associate (k0 => s%kw(1), k1 => s%kw(2))
      if (s%any_rigid) then
        s%g%mr(k0:k1, :) = 0.0_wp
        s%g%prx(k0:k1, :) = 0.0_wp
        s%g%pry(k0:k1, :) = 0.0_wp
      end if
      if (s%g%nf > 1) then
        s%g%gmx(k0:k1, :) = 0.0_wp
        s%g%gmy(k0:k1, :) = 0.0_wp
      end if
      if (size(s%g%gv, 2) > 0) s%g%gv(k0:k1, :) = 0.0_wp
    end associate
    !$omp end single
    simple = s%g%nf == 1 .and. .not. s%any_rigid .and. size(s%g%gv, 2) == 0
    do colour = 1, 2
      call strip_start(blk, s%sp, colour)
      do while (block_next(blk, b))
        if (simple) then
          call p2g_strip_simple(s%sp%perm(s%sp%start(b):s%sp%start(b + 1) - 1), s%sh%nm, s%sh%ns - s%sh%nm, &
                                s%sh%ovf, s%sh%idx, s%sh%w, s%sh%gx, s%sh%gy, s%sh%pidx, s%sh%pw, s%sh%pgx, &
                                s%sh%pgy, s%p%m, s%p%v, s%p%vol, s%p%sig, s%p%bf, s%opt%gravity, s%g%m, s%g%px, &
                                s%g%py, s%g%fx, s%g%fy)
        else
          call p2g_strip(s, s%sp%start(b), s%sp%start(b + 1) - 1)
        end if
      end do
      !$omp barrier
    end do
  end subroutine p2g

  subroutine p2g_strip_simple(perm, nm, np, ovf, idx, w, gx, gy, pidx, pw, pgx, pgy, pm, pv, pvol, psig, pbf, &
                              grav, m, px, py, fx, fy)
    !! P2G of the particles perm (one strip) for one velocity field without rigid
    !! particles (the common case): plain arrays, so the compiler knows nothing aliases.
    !! Main slots (nm per particle), then the particle's pool column (np slots), if any.
    integer(ik), intent(in) :: perm(:), nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: w(nm, *), gx(nm, *), gy(nm, *), pw(np, *), pgx(np, *), pgy(np, *), pm(*), pv(2, *), &
                            pvol(*), psig(4, *), pbf(2, *), grav(2)
    real(wp), intent(inout) :: m(*), px(*), py(*), fx(*), fy(*)
    integer(ik) :: i, ip, j
    real(wp) :: mp, mvx, mvy, sxx, syy, sxy, bx, by
    do i = 1, size(perm)
      ip = perm(i)
      mp = pm(ip)
      mvx = mp*pv(1, ip)
      mvy = mp*pv(2, ip)
      sxx = pvol(ip)*psig(1, ip)
      syy = pvol(ip)*psig(2, ip)
      sxy = pvol(ip)*psig(3, ip)
      bx = mp*(grav(1) + pbf(1, ip))
      by = mp*(grav(2) + pbf(2, ip))
      call p2g_slots(nm, idx(:, ip), w(:, ip), gx(:, ip), gy(:, ip))
      j = ovf(ip)
      if (j /= 0) call p2g_slots(np, pidx(:, j), pw(:, j), pgx(:, j), pgy(:, j))
    end do
  contains
    subroutine p2g_slots(ns, idx, w, gx, gy)
      !! Scatter of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: w(ns), gx(ns), gy(ns)
      integer(ik) :: a, k
      real(wp) :: wk, gxk, gyk
      do a = 1, ns
        k = idx(a)
        wk = w(a)
        gxk = gx(a)
        gyk = gy(a)
        m(k) = m(k) + wk*mp
        px(k) = px(k) + wk*mvx
        py(k) = py(k) + wk*mvy
        fx(k) = fx(k) - (sxx*gxk + sxy*gyk) + wk*bx
        fy(k) = fy(k) - (sxy*gxk + syy*gyk) + wk*by
      end do
    end subroutine p2g_slots
  end subroutine p2g_strip_simple

  subroutine p2g_strip(s, m0, m1)
    !! P2G of the particles perm(m0:m1) (one strip).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: m0, m1
    integer(ik) :: m, ip, k, a, f
    real(wp) :: mp, mvx, mvy, vol, sxx, syy, sxy, bx, by, wk, gxk, gyk, wm
    logical :: rig, multi, vols

    multi = s%g%nf > 1
    vols = size(s%g%gv, 2) > 0
    associate (g => s%g, p => s%p, sh => s%sh)
      do m = m0, m1
        ip = s%sp%perm(m)
        f = s%field(ip)
        mp = p%m(ip)
        mvx = mp*p%v(1, ip)
        mvy = mp*p%v(2, ip)
        vol = p%vol(ip)
        sxx = vol*p%sig(1, ip)
        syy = vol*p%sig(2, ip)
        sxy = vol*p%sig(3, ip)
        bx = mp*(s%opt%gravity(1) + p%bf(1, ip))
        by = mp*(s%opt%gravity(2) + p%bf(2, ip))
        rig = s%rigid(p%mat(ip))
        do a = 1, slot_count(sh, ip)
          call slot(sh, ip, a, k, wk, gxk, gyk)
          wm = wk*mp
          g%m(k, f) = g%m(k, f) + wm
          g%px(k, f) = g%px(k, f) + wk*mvx
          g%py(k, f) = g%py(k, f) + wk*mvy
          g%fx(k, f) = g%fx(k, f) - (sxx*gxk + sxy*gyk) + wk*bx
          g%fy(k, f) = g%fy(k, f) - (sxy*gxk + syy*gyk) + wk*by
          if (rig) then
            g%mr(k, f) = g%mr(k, f) + wm
            g%prx(k, f) = g%prx(k, f) + wk*mvx
            g%pry(k, f) = g%pry(k, f) + wk*mvy
          end if
          if (multi) then
            g%gmx(k, f) = g%gmx(k, f) + mp*gxk
            g%gmy(k, f) = g%gmy(k, f) + mp*gyk
          end if
          if (vols) g%gv(k, f) = g%gv(k, f) + wk*vol
        end do
      end do
    end associate
  end subroutine p2g_strip

  subroutine g2p(s, dt)
    !! Particle velocity (FLIP/PIC blend), position, and velocity gradient, each particle
    !! from its own velocity field; diagnostics summed block by block.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik) :: c, lo, hi
    type(blocks_t) :: blk
    logical :: musl, simple

    musl = s%opt%update == UPDATE_MUSL
    simple = s%g%nf == 1 .and. .not. s%any_rigid
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, s%p%n, lo, hi)
      if (simple) then
        call g2p_block_simple(lo, hi, s%sh%nm, s%sh%ns - s%sh%nm, s%sh%ovf, s%sh%idx, s%sh%w, s%sh%pidx, &
                              s%sh%pw, s%g%vx, s%g%vy, s%g%px, s%g%py, s%p%m, s%p%v, s%p%x, s%p%bf, s%opt%flip, &
                              dt, s%opt%gravity, s%g%origin, s%g%origin + real(s%g%ncell, wp)*s%g%h, &
                              s%g%walls /= WALL_OPEN, s%red(:, c))
        if (.not. musl) call vgrad_block(lo, hi, s%sh, s%g%vx, s%g%vy, s%p%L)
      else
        call g2p_block(s, dt, lo, hi, s%red(:, c))
      end if
    end do
    !$omp barrier
    !$omp single
    s%diag(4) = sum(s%red(1, :))
    s%diag(6) = sum(s%red(2, :))
    s%diag(7) = sum(s%red(3, :))
    s%diag(8) = s%diag(8) + sum(s%red(4, :))
    s%diag(9) = s%diag(9) + sum(s%red(5, :))
    s%diag(12) = sum(s%red(6, :))
    !$omp end single nowait
    ! With several fields (contact) the velocity gradient comes from the contact-corrected
    ! integrated velocity, the field that moved the particles: a MUSL remap of the
    ! particle momenta near a contact surface feeds approach velocity that contact
    ! removed back into the strain rate (measured: +37 % kinetic energy in a head-on
    ! collision of two elastic bars).
    if (musl .and. s%g%nf == 1) call musl_remap(s)
  end subroutine g2p

  subroutine g2p_block(s, dt, lo, hi, red)
    !! G2P of particles lo..hi; red = [kinetic energy, momentum x, y, work of gravity,
    !! work of body forces, wall clamps] of the block.
    type(sim_t), intent(inout) :: s
    real(wp), intent(in) :: dt
    integer(ik), intent(in) :: lo, hi
    real(wp), intent(out) :: red(6)
    integer(ik) :: ip, k, a, nclamp, f
    real(wp) :: dvx, dvy, vnx, vny, wk, gxk, gyk, flip, xo(2), xmin(2), xmax(2), ke, mom(2), wg, wb, mp
    logical :: musl, closed(4)

    flip = s%opt%flip
    musl = s%opt%update == UPDATE_MUSL
    call grid_box(s%g, xmin, xmax, closed)
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    wb = 0.0_wp
    nclamp = 0
    associate (g => s%g, p => s%p, sh => s%sh)
      do ip = lo, hi
        mp = p%m(ip)
        xo = p%x(:, ip)
        f = s%field(ip)
        if (s%rigid(p%mat(ip))) then
          p%v(:, ip) = s%mats(p%mat(ip))%vel
          p%x(:, ip) = xo + dt*p%v(:, ip)
          p%L(:, ip) = 0.0_wp
        else
          dvx = 0.0_wp
          dvy = 0.0_wp
          vnx = 0.0_wp
          vny = 0.0_wp
          do a = 1, slot_count(sh, ip)
            call slot(sh, ip, a, k, wk, gxk, gyk)
            vnx = vnx + wk*g%vx(k, f)
            vny = vny + wk*g%vy(k, f)
            dvx = dvx + wk*(g%vx(k, f) - g%px(k, f))
            dvy = dvy + wk*(g%vy(k, f) - g%py(k, f))
          end do
          p%v(1, ip) = flip*(p%v(1, ip) + dvx) + (1.0_wp - flip)*vnx
          p%v(2, ip) = flip*(p%v(2, ip) + dvy) + (1.0_wp - flip)*vny
          p%x(1, ip) = xo(1) + dt*vnx
          p%x(2, ip) = xo(2) + dt*vny
          if (.not. musl .or. g%nf > 1) p%L(:, ip) = velocity_gradient(sh, g%vx(:, f), g%vy(:, f), ip)
          call hold_walls(p%x(:, ip), xmin, xmax, closed, nclamp)
        end if
        ke = ke + 0.5_wp*mp*(p%v(1, ip)**2 + p%v(2, ip)**2)
        mom = mom + mp*p%v(:, ip)
        wg = wg + mp*dot_product(s%opt%gravity, p%x(:, ip) - xo)
        wb = wb + mp*dot_product(p%bf(:, ip), p%x(:, ip) - xo)
      end do
    end associate
    red = [ke, mom(1), mom(2), wg, wb, real(nclamp, wp)]
  end subroutine g2p_block

  subroutine g2p_block_simple(lo, hi, nm, np, ovf, idx, w, pidx, pw, vx, vy, vnx0, vny0, pm, pv, px, pbf, flip, &
                              dt, grav, xmin, xmax, closed, red)
    !! g2p_block for one velocity field without rigid particles (the common case), on plain
    !! arrays; the same arithmetic in the same order (main slots, then the pool column).
    !! vnx0, vny0: nodal velocity at t^n.
    integer(ik), intent(in) :: lo, hi, nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: w(nm, *), pw(np, *), vx(*), vy(*), vnx0(*), vny0(*), pm(*), pbf(2, *), flip, dt, &
                            grav(2), xmin(2), xmax(2)
    real(wp), intent(inout) :: pv(2, *), px(2, *)
    logical, intent(in) :: closed(4)
    real(wp), intent(out) :: red(6)
    integer(ik) :: ip, j, nclamp
    real(wp) :: dvx, dvy, vnx, vny, xo(2), ke, mom(2), wg, wb, mp
    ke = 0.0_wp
    mom = 0.0_wp
    wg = 0.0_wp
    wb = 0.0_wp
    nclamp = 0
    do ip = lo, hi
      mp = pm(ip)
      xo = px(:, ip)
      dvx = 0.0_wp
      dvy = 0.0_wp
      vnx = 0.0_wp
      vny = 0.0_wp
      call g2p_slots(nm, idx(:, ip), w(:, ip))
      j = ovf(ip)
      if (j /= 0) call g2p_slots(np, pidx(:, j), pw(:, j))
      pv(1, ip) = flip*(pv(1, ip) + dvx) + (1.0_wp - flip)*vnx
      pv(2, ip) = flip*(pv(2, ip) + dvy) + (1.0_wp - flip)*vny
      px(1, ip) = xo(1) + dt*vnx
      px(2, ip) = xo(2) + dt*vny
      call hold_walls(px(:, ip), xmin, xmax, closed, nclamp)
      ke = ke + 0.5_wp*mp*(pv(1, ip)**2 + pv(2, ip)**2)
      mom = mom + mp*pv(:, ip)
      wg = wg + mp*dot_product(grav, px(:, ip) - xo)
      wb = wb + mp*dot_product(pbf(:, ip), px(:, ip) - xo)
    end do
    red = [ke, mom(1), mom(2), wg, wb, real(nclamp, wp)]
  contains
    subroutine g2p_slots(ns, idx, w)
      !! Gather of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: w(ns)
      integer(ik) :: a, k
      real(wp) :: wk
      do a = 1, ns
        k = idx(a)
        wk = w(a)
        vnx = vnx + wk*vx(k)
        vny = vny + wk*vy(k)
        dvx = dvx + wk*(vx(k) - vnx0(k))
        dvy = dvy + wk*(vy(k) - vny0(k))
      end do
    end subroutine g2p_slots
  end subroutine g2p_block_simple

  subroutine vgrad_block(lo, hi, sh, vx, vy, l)
    !! Velocity gradient of particles lo..hi from one nodal velocity field (the same sums as
    !! velocity_gradient), main slots then pool column on plain arrays (vgrad_plain).
    !! The general paths keep velocity_gradient: calling this from them changes contact runs
    !! in the last bits (the compiler vectorises these sums without FMA contraction), so
    !! merging the two needs its own gold regeneration.
    integer(ik), intent(in) :: lo, hi
    type(shape_t), intent(in) :: sh
    real(wp), intent(in) :: vx(*), vy(*)
    real(wp), intent(inout) :: l(4, *)
    call vgrad_plain(lo, hi, sh%nm, sh%ns - sh%nm, sh%ovf, sh%idx, sh%gx, sh%gy, sh%pidx, sh%pgx, sh%pgy, vx, vy, l)
  end subroutine vgrad_block

  subroutine vgrad_plain(lo, hi, nm, np, ovf, idx, gx, gy, pidx, pgx, pgy, vx, vy, l)
    !! vgrad_block on plain arrays: nm main slots per particle, np in its pool column.
    integer(ik), intent(in) :: lo, hi, nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: gx(nm, *), gy(nm, *), pgx(np, *), pgy(np, *), vx(*), vy(*)
    real(wp), intent(inout) :: l(4, *)
    integer(ik) :: ip, j
    real(wp) :: l1, l2, l3, l4
    do ip = lo, hi
      l1 = 0.0_wp
      l2 = 0.0_wp
      l3 = 0.0_wp
      l4 = 0.0_wp
      call vgrad_slots(nm, idx(:, ip), gx(:, ip), gy(:, ip))
      j = ovf(ip)
      if (j /= 0) call vgrad_slots(np, pidx(:, j), pgx(:, j), pgy(:, j))
      l(:, ip) = [l1, l2, l3, l4]
    end do
  contains
    subroutine vgrad_slots(ns, idx, gx, gy)
      !! Sums of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: gx(ns), gy(ns)
      integer(ik) :: a, k
      do a = 1, ns
        k = idx(a)
        l1 = l1 + vx(k)*gx(a)
        l2 = l2 + vy(k)*gx(a)
        l3 = l3 + vx(k)*gy(a)
        l4 = l4 + vy(k)*gy(a)
      end do
    end subroutine vgrad_slots
  end subroutine vgrad_plain

  subroutine remap_strip_simple(perm, nm, np, ovf, idx, w, pidx, pw, pm, pv, qx, qy)
    !! MUSL momentum scatter of the particles perm (one strip) to one field, plain arrays
    !! (main slots, then the pool column).
    integer(ik), intent(in) :: perm(:), nm, np, ovf(*), idx(nm, *), pidx(np, *)
    real(wp), intent(in) :: w(nm, *), pw(np, *), pm(*), pv(2, *)
    real(wp), intent(inout) :: qx(*), qy(*)
    integer(ik) :: i, ip, j
    real(wp) :: mvx, mvy
    do i = 1, size(perm)
      ip = perm(i)
      mvx = pm(ip)*pv(1, ip)
      mvy = pm(ip)*pv(2, ip)
      call remap_slots(nm, idx(:, ip), w(:, ip))
      j = ovf(ip)
      if (j /= 0) call remap_slots(np, pidx(:, j), pw(:, j))
    end do
  contains
    subroutine remap_slots(ns, idx, w)
      !! Scatter of ns slots of the current particle.
      integer(ik), intent(in) :: ns, idx(ns)
      real(wp), intent(in) :: w(ns)
      integer(ik) :: a, k
      do a = 1, ns
        k = idx(a)
        qx(k) = qx(k) + w(a)*mvx
        qy(k) = qy(k) + w(a)*mvy
      end do
    end subroutine remap_slots
  end subroutine remap_strip_simple

  pure function velocity_gradient(sh, vx, vy, ip) result(l)
    !! L_p = sum_i v_i (x) grad S_ip, layout [L11, L21, L12, L22].
    type(shape_t), intent(in) :: sh
    real(wp), intent(in) :: vx(:), vy(:)
    integer(ik), intent(in) :: ip
    real(wp) :: l(4)
    integer(ik) :: a, k
    real(wp) :: wk, gxk, gyk
    l = 0.0_wp
    do a = 1, slot_count(sh, ip)
      call slot(sh, ip, a, k, wk, gxk, gyk)
      l(1) = l(1) + vx(k)*gxk
      l(2) = l(2) + vy(k)*gxk
      l(3) = l(3) + vx(k)*gyk
      l(4) = l(4) + vy(k)*gyk
    end do
  end function velocity_gradient

  subroutine musl_remap(s)
    !! MUSL: map the updated particle momentum back to the grid and take the velocity
    !! gradient from that field (Sulsky et al. 1994); rigid nodes and walls apply. Not
    !! used with contact (see g2p).
    type(sim_t), intent(inout) :: s
    integer(ik) :: ip, k, f, b, colour, c, lo, hi
    type(blocks_t) :: blk
    do f = 1, s%g%nf   ! field by field: a row of fields per node was a strided loop per node
      !$omp do schedule(static) private(k)
      do k = s%kw(1), s%kw(2)
        s%g%vx(k, f) = 0.0_wp
        s%g%vy(k, f) = 0.0_wp
      end do
      !$omp end do
    end do
    do colour = 1, 2
      call strip_start(blk, s%sp, colour)
      do while (block_next(blk, b))
        if (s%g%nf == 1) then
          call remap_strip_simple(s%sp%perm(s%sp%start(b):s%sp%start(b + 1) - 1), s%sh%nm, s%sh%ns - s%sh%nm, &
                                  s%sh%ovf, s%sh%idx, s%sh%w, s%sh%pidx, s%sh%pw, s%p%m, s%p%v, s%g%vx, s%g%vy)
        else
          call remap_strip(s, s%sp%start(b), s%sp%start(b + 1) - 1)
        end if
      end do
      !$omp barrier
    end do
    call momentum_to_velocity(s%g, s%mtol, s%kw, s%g%vx, s%g%vy)
    !$omp single
    if (s%any_rigid) call impose_rigid(s%g, s%kw, s%g%vx, s%g%vy)
    do f = 1, s%g%nf
      call grid_apply_walls(s%g, s%g%vx(:, f), s%g%vy(:, f))
    end do
    !$omp end single
    call block_start(blk)
    do while (block_next(blk, c))
      call chunk_range(c, s%p%n, lo, hi)
      if (s%g%nf == 1 .and. .not. s%any_rigid) then
        call vgrad_block(lo, hi, s%sh, s%g%vx, s%g%vy, s%p%L)
        cycle
      end if
      do ip = lo, hi
        if (s%rigid(s%p%mat(ip))) cycle
        f = s%field(ip)
        s%p%L(:, ip) = velocity_gradient(s%sh, s%g%vx(:, f), s%g%vy(:, f), ip)
      end do
    end do
    !$omp barrier
  end subroutine musl_remap

  subroutine remap_strip(s, m0, m1)
    !! MUSL momentum scatter of the particles perm(m0:m1) (one strip).
    type(sim_t), intent(inout) :: s
    integer(ik), intent(in) :: m0, m1
    integer(ik) :: m, ip, k, a, f
    real(wp) :: mvx, mvy, wk, gxk, gyk
    associate (g => s%g, p => s%p, sh => s%sh)
      do m = m0, m1
        ip = s%sp%perm(m)
        f = s%field(ip)
        mvx = p%m(ip)*p%v(1, ip)
        mvy = p%m(ip)*p%v(2, ip)
        do a = 1, slot_count(sh, ip)
          call slot(sh, ip, a, k, wk, gxk, gyk)
          g%vx(k, f) = g%vx(k, f) + wk*mvx
          g%vy(k, f) = g%vy(k, f) + wk*mvy
        end do
      end do
    end associate
  end subroutine remap_strip

  pure subroutine hold_walls(x, xmin, xmax, closed, nclamp)
    !! cpdi_grid's hold_on_walls (particles held on closed walls; nclamp counts them), copied
    !! here so that the G2P loops inline it instead of a call per particle into cpdi_grid
    !! (no arithmetic: comparisons and copies only).
    real(wp), intent(inout) :: x(2)
    real(wp), intent(in) :: xmin(2), xmax(2)
    logical, intent(in) :: closed(4)
    integer(ik), intent(inout) :: nclamp
    integer :: a
    do a = 1, 2   ! closed = (left, right, bottom, top)
      if (closed(2*a - 1) .and. x(a) < xmin(a)) then
        x(a) = xmin(a)
        nclamp = nclamp + 1
      end if
      if (closed(2*a) .and. x(a) > xmax(a)) then
        x(a) = xmax(a)
        nclamp = nclamp + 1
      end if
    end do
  end subroutine hold_walls

  pure integer(ik) function slot_count(sh, ip)
    !! Slots in use by particle ip (cpdi_shape's shape_count). A copy in this module so that the
    !! general transfers' slot loops inline it: shape_slot, in cpdi_shape, was a call per slot
    !! (about a tenth of a contact run's step).
    type(shape_t), intent(in) :: sh
    integer(ik), intent(in) :: ip
    slot_count = sh%nm
    if (sh%ovf(ip) /= 0) slot_count = sh%ns
  end function slot_count

  pure subroutine slot(sh, ip, a, k, w, gx, gy)
    !! Slot a (1..slot_count) of particle ip: main slot a, or pool slot a - nm (cpdi_shape's
    !! shape_slot, copied here for inlining; see slot_count).
    type(shape_t), intent(in) :: sh
    integer(ik), intent(in) :: ip, a
    integer(ik), intent(out) :: k
    real(wp), intent(out) :: w, gx, gy
    if (a <= sh%nm) then
      k = sh%idx(a, ip)
      w = sh%w(a, ip)
      gx = sh%gx(a, ip)
      gy = sh%gy(a, ip)
    else
      k = sh%pidx(a - sh%nm, sh%ovf(ip))
      w = sh%pw(a - sh%nm, sh%ovf(ip))
      gx = sh%pgx(a - sh%nm, sh%ovf(ip))
      gy = sh%pgy(a - sh%nm, sh%ovf(ip))
    end if
  end subroutine slot
end module cpdi_transfer
