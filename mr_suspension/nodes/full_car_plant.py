"""Full-car plant node: the body (heave, pitch, roll) on four corners over a four-wheel road.

Runs in the car's namespace (default ``/``) and publishes every corner's contract topics under
its corner namespace (``front_left/imu/body``, ..., see ``msg_defs/topics.yaml``): ``imu/body``
(the body point above the corner), ``imu/wheel``, ``stroke``, ``truth/state``,
``truth/tyre_force``; plus the body IMU at the centre of gravity on ``body/imu`` and, in
lock-step, ``/clock``. Subscribes to each corner's ``damper/force``. So per corner today's
controller and actuator nodes run unchanged in the corner's namespace (vehicle parameter
``<full car>:<corner>``), or the modal controller replaces the four controllers.

The model is :class:`~mr_suspension.sim.full_car_stepper.FullCarPlantStepper`; the loop (start
handshake, real time and lock-step, re-sends, statistics) is
:class:`~mr_suspension.nodes.plant_base.PlantBase`, the quarter-car plant's: a step waits for,
or in real time takes the newest of, the damper forces of all four corners. Lock-step with
``coupling_delay: 0`` is :func:`~mr_suspension.sim.full_car_sim.simulate`'s step order.
"""

from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.core import car_road
from mr_suspension.nodes import cdr, common, contract as c
from mr_suspension.nodes.plant import corner_templates
from mr_suspension.nodes.plant_base import PlantBase
from mr_suspension.sim.full_car_stepper import FullCarPlantStepper

NODE = 'full_car_plant'


class FullCarPlantNode(PlantBase):
    """Full car with four-wheel road, each corner's sensors and ground truth, and a body IMU."""

    def __init__(self, context=None, parameter_overrides=None, **kwargs):
        super().__init__(NODE, tuple(f'{corner}/' for corner in c.CORNERS), context=context,
                         parameter_overrides=parameter_overrides, **kwargs)

    def _declare_model(self, defaults):
        self.config = common.declare_full_car(self, defaults)
        self.dt = self.config.dt
        self.gravity = self.config.car.front.g
        if self.config.car.rear.g != self.gravity:
            raise ValueError('full_car_plant: front and rear corners must share gravity g')
        self.body_imu_subscribers = common.declare(
            self, defaults, 'body_imu_subscribers', 'Start once body/imu has this many '
            'subscribers (the modal controller if used, plus recorders)', 0, 100)

    def _make_road(self, spec, duration):
        car = self.config.car
        return car_road.from_spec(spec, duration=duration, dt=self.dt,
                                  wheelbase=car.wheelbase, track=car.track_f)

    def _make_stepper(self):
        return FullCarPlantStepper(self.config, self.road)

    def _create_outputs(self):
        ls = self.lockstep
        self.corner_pubs = []
        self.corner_tpls = []
        for prefix in self.corners:
            pubs = (self.create_publisher(Imu, prefix + c.IMU_BODY, common.qos(c.IMU_BODY, ls)),
                    self.create_publisher(Imu, prefix + c.IMU_WHEEL,
                                          common.qos(c.IMU_WHEEL, ls)),
                    self.create_publisher(JointState, prefix + c.STROKE,
                                          common.qos(c.STROKE, ls)),
                    self.create_publisher(JointState, prefix + c.TRUTH_STATE,
                                          common.qos(c.TRUTH_STATE, ls)),
                    self.create_publisher(Float64, prefix + c.TRUTH_TYRE_FORCE,
                                          common.qos(c.TRUTH_TYRE_FORCE, ls)))
            for name, pub in zip((c.IMU_BODY, c.IMU_WHEEL, c.STROKE, c.TRUTH_STATE,
                                  c.TRUTH_TYRE_FORCE), pubs):
                self.own[prefix + name] = pub
            self.corner_pubs.append(pubs)
            self.corner_tpls.append(corner_templates())
        self.pub_body_imu = self.create_publisher(Imu, c.BODY_IMU, common.qos(c.BODY_IMU, ls))
        self.own[c.BODY_IMU] = self.pub_body_imu
        self.tpl_body_imu = body_imu_template()

    def _ready_extra(self):
        return self.pub_body_imu.get_subscription_count() >= self.body_imu_subscribers

    def _describe(self):
        return f', {self.config.car.m_b:g} kg body on {len(self.corners)} corners'

    def _sample(self, ns):
        p = self.plant
        g = self.gravity
        motion, sensors, other = [], [], []
        for i, (pubs, tpls) in enumerate(zip(self.corner_pubs, self.corner_tpls)):
            pub_s, pub_u, pub_x, pub_truth, pub_tyre = pubs
            tpl_s, tpl_u, tpl_x, tpl_truth, tpl_tyre = tpls
            x, v = p.motion(i)
            z_s, v_s = p.body_point(i)
            z_u, v_u = p.wheel(i)
            z_r, zr_dot = p.road_now(i)
            motion.append((pub_truth, tpl_truth.pack(ns, z_s, z_u, z_r, x, v_s, v_u, zr_dot, v)))
            sensors += [(pub_s, tpl_s.pack(ns, p.a_s(i) + g)),
                        (pub_u, tpl_u.pack(ns, p.a_u(i) + g)),
                        (pub_x, tpl_x.pack(ns, x))]
            other.append((pub_tyre, tpl_tyre.pack(ns, float(p.f_t[i]))))
        a_z, w_pitch, w_roll = p.imu()
        sensors.append((self.pub_body_imu, self.tpl_body_imu.pack(ns, w_roll, w_pitch, a_z + g)))
        return motion, sensors, other

    def _coupled(self, i, f_m, c_m, v_m):
        return self.plant.coupled(i, f_m, c_m, v_m)

    def _step(self, forces, tangents):
        self.plant.step(forces, tangents)


def body_imu_template():
    """Return the serialized template of ``body/imu`` (roll rate, pitch rate, vertical force)."""
    imu = Imu()
    imu.header.frame_id = c.FRAME_BODY_IMU_CG
    imu.orientation_covariance[0] = -1.0
    return cdr.Template(imu, ('angular_velocity.x', 'angular_velocity.y',
                              'linear_acceleration.z'))


def main(args=None):
    """Console script ``full_car_plant``."""
    return common.run(FullCarPlantNode, args)


if __name__ == '__main__':
    main()
