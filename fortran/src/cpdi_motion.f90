!> Prescribed motion of rigid bodies: a velocity table, piecewise linear in time.
module cpdi_motion
  !! A `rigid` material moves with its prescribed velocity. With a table of rows (t_k, vx_k, vy_k)
  !! that velocity is piecewise linear in time between the rows, held at the first row's value
  !! before t_1 and at the last row's after t_n. A step from t to t + dt moves the body with the
  !! table's mean velocity over the step, (D(t + dt) - D(t)) / dt, D the table's displacement
  !! integral: the body's displacement is then D(t) - D(0) to round-off, whatever the step sizes
  !! and wherever the breakpoints fall, and the water sees the velocity that moves the body.
  use cpdi_kinds, only: wp, ik
  use cpdi_status, only: status_t, CPDI_ERR_INPUT, CPDI_ERR_ALLOC
  use cpdi_particles, only: particles_t
  use cpdi_materials, only: material_t
  implicit none
  private

  type, public :: vtable_t
    !! The velocity table of one material (n = 0: none, the material's constant velocity).
    integer(ik) :: n = 0
    real(wp), allocatable :: t(:)       !! times [s], strictly increasing
    real(wp), allocatable :: v(:, :)    !! velocities (2, n) [m/s]
    real(wp), allocatable :: d(:, :)    !! displacement integral at each time, from t(1) [m]
  end type vtable_t

  public :: vtable_set, vtable_displacement, vtable_mean, motion_apply

contains

  subroutine vtable_set(tb, rows, st)
    !! Build a table from rows(3, n) = (t, vx, vy); the times must be finite and strictly increasing.
    type(vtable_t), intent(inout) :: tb
    real(wp), intent(in) :: rows(:, :)
    type(status_t), intent(inout) :: st
    integer(ik) :: k, n, ierr
    character(len=200) :: buf
    n = size(rows, 2)
    if (n < 1 .or. size(rows, 1) /= 3) then
      call st%set(CPDI_ERR_INPUT, 'a velocity table needs at least one row of (t, vx, vy)')
      return
    end if
    if (.not. all(abs(rows) <= huge(1.0_wp))) then
      call st%set(CPDI_ERR_INPUT, 'the velocity table has a NaN or infinite entry; give finite SI values')
      return
    end if
    do k = 2, n
      if (.not. (rows(1, k) > rows(1, k - 1))) then
        write (buf, '(a,i0,a)') 'the velocity table''s times must increase strictly (row ', k, &
          ' does not); sort the rows by time'
        call st%set(CPDI_ERR_INPUT, trim(buf))
        return
      end if
    end do
    if (allocated(tb%t)) deallocate (tb%t, tb%v, tb%d)
    allocate (tb%t(n), tb%v(2, n), tb%d(2, n), stat=ierr)
    if (ierr /= 0) then
      call st%set(CPDI_ERR_ALLOC, 'could not allocate the velocity table')
      return
    end if
    tb%n = n
    tb%t = rows(1, :)
    tb%v = rows(2:3, :)
    tb%d(:, 1) = 0.0_wp
    do k = 2, n
      tb%d(:, k) = tb%d(:, k - 1) + 0.5_wp*(tb%t(k) - tb%t(k - 1))*(tb%v(:, k - 1) + tb%v(:, k))
    end do
  end subroutine vtable_set

  pure function vtable_displacement(tb, t) result(d)
    !! The integral of the table's velocity from t(1) to t [m] (negative before t(1)).
    type(vtable_t), intent(in) :: tb
    real(wp), intent(in) :: t
    real(wp) :: d(2), s
    integer(ik) :: k
    if (t <= tb%t(1)) then
      d = tb%v(:, 1)*(t - tb%t(1))
      return
    end if
    if (t >= tb%t(tb%n)) then
      d = tb%d(:, tb%n) + tb%v(:, tb%n)*(t - tb%t(tb%n))
      return
    end if
    k = 1
    do while (tb%t(k + 1) <= t)
      k = k + 1
    end do
    s = t - tb%t(k)
    d = tb%d(:, k) + s*tb%v(:, k) + 0.5_wp*s*s*(tb%v(:, k + 1) - tb%v(:, k))/(tb%t(k + 1) - tb%t(k))
  end function vtable_displacement

  pure function vtable_mean(tb, t, dt) result(v)
    !! The table's mean velocity over [t, t + dt] [m/s].
    type(vtable_t), intent(in) :: tb
    real(wp), intent(in) :: t, dt
    real(wp) :: v(2)
    v = (vtable_displacement(tb, t + dt) - vtable_displacement(tb, t))/dt
  end function vtable_mean

  subroutine motion_apply(tabs, t, dt, mats, p, rvel)
    !! Before a step from t to t + dt: every material with a table gets the table's mean velocity
    !! over the step as its prescribed velocity (mats%vel, the incompressible water's copy rvel
    !! when it has one), and so do its particles (their momentum is the rigid nodes' velocity).
    type(vtable_t), intent(in) :: tabs(:)
    real(wp), intent(in) :: t, dt
    type(material_t), intent(inout) :: mats(:)
    type(particles_t), intent(inout) :: p
    real(wp), allocatable, intent(inout) :: rvel(:, :)
    integer(ik) :: m, ip
    logical :: any_table
    any_table = .false.
    do m = 1, min(size(tabs), size(mats))
      if (tabs(m)%n == 0) cycle
      any_table = .true.
      mats(m)%vel = vtable_mean(tabs(m), t, dt)
      if (allocated(rvel)) rvel(:, m) = mats(m)%vel
    end do
    if (.not. any_table) return
    do ip = 1, p%n
      m = p%mat(ip)
      if (m > size(tabs)) cycle
      if (tabs(m)%n > 0) p%v(:, ip) = mats(m)%vel
    end do
  end subroutine motion_apply
end module cpdi_motion
