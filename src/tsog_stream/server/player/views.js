// tsog-stream web player: where the camera starts. The manifest's `view` (its first capture
// camera, or a framing of the dense core) and its capture `cameras` become poses in the engine's
// world, where the scene is turned so its up axis (the cameras' up, COLMAP's -y without them)
// is +y. A capture camera looks along +z with y down (COLMAP/OpenCV); an engine camera looks
// along -z with y up: same position, rotation columns (x, -y, -z). See docs/design/player.md.

/** Vertical fields of view a stored camera may give, in degrees: the CPU renderer's range
 * (render/camera.py FOCAL_PER_SIDE: a focal length of 0.02-50 image sides). */
export const FOV_RANGE_DEG = [1.1, 175];

const AXES = { y: [0, 1, 0], '-y': [0, -1, 0], z: [0, 0, 1], '-z': [0, 0, -1], x: [1, 0, 0], '-x': [-1, 0, 0] };

/** The scene's up axis: `?up=` when given, else the mean up (-y column) of the capture cameras
 * or of the opening view, else +y (indexes written before views were stored, and links that
 * give yaw/pitch/distance, written when +y was every scene's up). */
export function sceneUp(manifest, upParam, legacy = false) {
    if (upParam) return AXES[upParam];
    if (legacy) return [0, 1, 0];
    const poses = manifest.cameras?.length ? manifest.cameras : manifest.view ? [manifest.view] : [];
    if (!poses.length) return [0, 1, 0];
    const sum = [0, 0, 0];
    for (const c of poses) for (let i = 0; i < 3; i++) sum[i] -= c.rotation[i][1];
    const norm = Math.hypot(...sum);
    return norm > 1e-6 ? sum.map((v) => v / norm) : [0, 1, 0];
}

export const UP_CHOICES = Object.keys(AXES);

/** The rotation (pc.Quat) that turns `up` to the engine's +y. */
export function upRotation(pc, up) {
    const [x, y, z] = up;
    const dot = Math.max(-1, Math.min(1, y));
    const axis = new pc.Vec3(z, 0, -x); // up x (+y), normalised below
    if (axis.length() < 1e-9) {
        return dot > 0 ? new pc.Quat() : new pc.Quat().setFromAxisAngle(pc.Vec3.RIGHT, 180);
    }
    return new pc.Quat().setFromAxisAngle(axis.normalize(), Math.acos(dot) * (180 / Math.PI));
}

/** A capture camera as an engine pose: position and rotation in the world, vertical fov. */
export function capturePose(pc, camera, turn) {
    const r = camera.rotation; // camera-to-world, row by row; columns x right, y down, z forward
    const m = new pc.Mat4();
    const d = m.data; // column-major
    for (let i = 0; i < 3; i++) {
        d[i] = r[i][0];
        d[4 + i] = -r[i][1];
        d[8 + i] = -r[i][2];
    }
    const local = new pc.Quat().setFromMat4(m);
    const rotation = new pc.Quat().mul2(turn, local);
    const position = turn.transformVector(new pc.Vec3(...camera.position), new pc.Vec3());
    const stored = 2 * Math.atan(camera.height / (2 * camera.fy)) * (180 / Math.PI);
    const fov = Math.min(Math.max(stored, FOV_RANGE_DEG[0]), FOV_RANGE_DEG[1]);
    return { position, rotation, fov, name: camera.name };
}

/** How far ahead of a pose the orbit pivots: to the dense core's centre along the view, or
 * the core's radius when the core is behind or beside the camera. */
export function pivotDistance(pc, pose, core, turn) {
    if (!core) return 1;
    const centre = turn.transformVector(new pc.Vec3(...core.center), new pc.Vec3());
    const forward = pose.rotation.transformVector(new pc.Vec3(0, 0, -1), new pc.Vec3());
    const ahead = centre.sub(pose.position).dot(forward);
    return ahead > 0.05 * core.radius ? ahead : core.radius;
}
