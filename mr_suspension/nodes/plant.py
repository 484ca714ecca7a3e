"""Plant node: integrates the corner over a road and publishes the sensors and ground truth.

Publishes (relative names, see ``msg_defs/topics.yaml``) ``imu/body``, ``imu/wheel``, ``stroke``,
``truth/state``, ``truth/tyre_force`` and, in lock-step mode, ``/clock``; subscribes to
``damper/force``. Sample ``k`` carries the state at ``t_k = k dt`` and the accelerations and tyre
force of the step that ended there.

* Real time (``lockstep: false``): a wall timer at ``rate``; each tick advances one step with the
  newest damper force, moved to the present stroke rate along its tangent
  (:meth:`~mr_suspension.sim.stepper.PlantStepper.coupled`). If the force of the present sample
  has not arrived yet the force of the sample before is used: one sample of coupling latency,
  stable because the stiff part acts through the tangent inside the implicit step. With
  ``sensors_after_force`` (default) a sample's sensors and tyre force go out once its damper
  force is in (before the next step at the latest), so their readers do not take the CPU the
  actuator needs for the force.
* Lock-step (``lockstep: true``): after publishing sample ``k`` the plant waits for the damper
  force of sample ``k - coupling_delay``, then steps; time is simulated and published on
  ``/clock``. With ``coupling_delay: 0`` this is the simulator's step order exactly,
  reproducible and faster than real time.

The loop itself (start-up, both modes, re-sends, statistics) is
:class:`~mr_suspension.nodes.plant_base.PlantBase`, shared with the full-car plant.
"""

from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.core import road as rd
from mr_suspension.nodes import cdr, common, contract as c
from mr_suspension.nodes.plant_base import parse_road, PlantBase
from mr_suspension.sim.stepper import PlantStepper

NODE = 'plant'
__all__ = ['main', 'NODE', 'parse_road', 'PlantNode']


class PlantNode(PlantBase):
    """Quarter-car plant with road, sensors and ground truth."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, ('',), context=context, parameter_overrides=parameter_overrides,
                         **kwargs)

    def _declare_model(self, defaults):
        self.config = common.declare_corner(self, defaults)
        self.dt = self.config.dt
        self.gravity = self.config.car.g

    def _make_road(self, spec, duration):
        return rd.from_spec(spec, duration=duration, dt=self.dt)

    def _make_stepper(self):
        return PlantStepper(self.config, self.road)

    def _describe(self):
        options = self.config.car.options_on  # corner-level model options of the vehicle set
        return f', corner options: {", ".join(options)}' if options else ''

    def _create_outputs(self):
        ls = self.lockstep
        self.pub_imu_s = self.create_publisher(Imu, c.IMU_BODY, common.qos(c.IMU_BODY, ls))
        self.pub_imu_u = self.create_publisher(Imu, c.IMU_WHEEL, common.qos(c.IMU_WHEEL, ls))
        self.pub_stroke = self.create_publisher(JointState, c.STROKE, common.qos(c.STROKE, ls))
        self.pub_truth = self.create_publisher(JointState, c.TRUTH_STATE,
                                               common.qos(c.TRUTH_STATE, ls))
        self.pub_tyre = self.create_publisher(Float64, c.TRUTH_TYRE_FORCE,
                                              common.qos(c.TRUTH_TYRE_FORCE, ls))
        self.own.update({c.IMU_BODY: self.pub_imu_s, c.IMU_WHEEL: self.pub_imu_u,
                         c.STROKE: self.pub_stroke, c.TRUTH_STATE: self.pub_truth,
                         c.TRUTH_TYRE_FORCE: self.pub_tyre})
        (self.tpl_imu_s, self.tpl_imu_u, self.tpl_stroke, self.tpl_truth,
         self.tpl_tyre) = corner_templates()

    def _sample(self, ns):
        p = self.plant
        x = p.stroke
        z_r, zr_dot = p.road_now()
        q = p.q
        truth = self.tpl_truth.pack(ns, float(q[0]), float(q[1]), z_r, x, float(q[2]),
                                    float(q[3]), zr_dot, p.stroke_rate)
        sensors = ((self.pub_imu_s, self.tpl_imu_s.pack(ns, p.a_s + self.gravity)),
                   (self.pub_imu_u, self.tpl_imu_u.pack(ns, p.a_u + self.gravity)),
                   (self.pub_stroke, self.tpl_stroke.pack(ns, x)))
        return (((self.pub_truth, truth),), sensors,
                ((self.pub_tyre, self.tpl_tyre.pack(ns, p.f_t)),))

    def _coupled(self, i, f_m, c_m, v_m):
        return self.plant.coupled(f_m, c_m, v_m)

    def _step(self, forces, tangents):
        self.plant.step(forces[0], tangents[0])


def corner_templates():
    """Return serialized templates of a corner's messages (:class:`cdr.Template`).

    Returns ``(imu/body, imu/wheel, stroke, truth/state, truth/tyre_force)``.
    """
    imu_s, imu_u = Imu(), Imu()
    imu_s.header.frame_id = c.FRAME_BODY_IMU
    imu_u.header.frame_id = c.FRAME_WHEEL_IMU
    for m in (imu_s, imu_u):
        m.orientation_covariance[0] = -1.0
        m.angular_velocity_covariance[0] = -1.0
    stroke = JointState()
    stroke.header.frame_id = c.FRAME_SUSPENSION
    stroke.name = [c.JOINT_STROKE]
    stroke.position = [0.0]
    truth = JointState()
    truth.header.frame_id = c.FRAME_WORLD
    truth.name = list(c.JOINTS_TRUTH)
    truth.position = [0.0] * len(c.JOINTS_TRUTH)
    truth.velocity = [0.0] * len(c.JOINTS_TRUTH)
    n = len(c.JOINTS_TRUTH)
    return (cdr.Template(imu_s, ('linear_acceleration.z',)),
            cdr.Template(imu_u, ('linear_acceleration.z',)),
            cdr.Template(stroke, ('position[0]',)),
            cdr.Template(truth, [f'position[{i}]' for i in range(n)]
                         + [f'velocity[{i}]' for i in range(n)]),
            cdr.Template(Float64(), ('data',), stamped=False))


def main(args=None):
    """Console script ``plant``."""
    return common.run(PlantNode, args)


if __name__ == '__main__':
    main()
