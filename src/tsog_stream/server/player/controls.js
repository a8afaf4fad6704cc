// tsog-stream web player: the camera people expect. Orbit (drag), pan (right or shift drag,
// two fingers), zoom (wheel, pinch), fly (WASD/QE, and dragging turns the view in place in fly
// mode), double-click to pivot on a point, capture-camera presets and reset. The state is a
// pivot (target), a distance and yaw/pitch about the world's +y; a capture camera's exact pose
// (roll included) is kept until the first move. See docs/design/player.md ("Controls").

const DEG = Math.PI / 180;
const ORBIT_DEG_PER_PX = 0.3;
const ZOOM_PER_WHEEL = 0.001;
const FLY_RADII_PER_S = 0.75; // WASD speed in core radii per second (shift: 4x)
const MIN_PITCH = -89;
const MAX_PITCH = 89;

/** Yaw and pitch (degrees) of a forward direction: the inverse of CameraControls.forward. */
export function anglesOf(forward) {
    const f = forward.clone().normalize();
    return { yaw: Math.atan2(-f.x, -f.z) / DEG, pitch: Math.asin(Math.max(-1, Math.min(1, f.y))) / DEG };
}

export class CameraControls {
    /** `entity` holds a camera component; `element` receives the pointer events; `scale` is
     * the scene's size (its dense core's radius) that speeds and limits are measured in. */
    constructor(pc, entity, element, scale) {
        this.pc = pc;
        this.entity = entity;
        this.element = element;
        this.scale = scale;
        this.target = new pc.Vec3();
        this.distance = scale;
        this.yaw = 0;
        this.pitch = -15;
        this.mode = 'orbit';
        this.exact = null; // { position, rotation } of a capture camera until the first move
        this.home = null;
        this.keys = new Set();
        this.pointers = new Map();
        this.moved = 0; // counts moves, so a link can say whether a preset is still in view
        this.bindPointer(element);
    }

    /** Look from `position` along the rotation `rotation` (a pc.Quat) exactly; the orbit
     * pivots `pivot` units ahead. */
    setPose(position, rotation, pivot) {
        const pc = this.pc;
        const forward = rotation.transformVector(new pc.Vec3(0, 0, -1), new pc.Vec3());
        const { yaw, pitch } = anglesOf(forward);
        this.yaw = yaw;
        this.pitch = pitch;
        this.distance = pivot;
        this.target.copy(position).add(forward.mulScalar(pivot));
        this.exact = { position: position.clone(), rotation: rotation.clone() };
    }

    /** Orbit `target` from `distance` at yaw/pitch degrees. */
    setOrbit(target, distance, yaw, pitch) {
        this.target.copy(target);
        this.distance = distance;
        this.yaw = yaw;
        this.pitch = Math.min(MAX_PITCH, Math.max(MIN_PITCH, pitch));
        this.exact = null;
    }

    /** Remember the current view as the one `reset` returns to. */
    saveHome() {
        this.home = this.snapshot();
    }

    reset() {
        if (this.home) this.restore(this.home);
    }

    snapshot() {
        const exact = this.exact && { position: this.exact.position.clone(), rotation: this.exact.rotation.clone() };
        return { target: this.target.clone(), distance: this.distance, yaw: this.yaw, pitch: this.pitch, exact };
    }

    restore(s) {
        this.setOrbit(s.target, s.distance, s.yaw, s.pitch);
        this.exact = s.exact && { position: s.exact.position.clone(), rotation: s.exact.rotation.clone() };
        this.moved += 1;
    }

    /** The unit view direction for the current yaw and pitch. */
    forward() {
        const yaw = this.yaw * DEG;
        const pitch = this.pitch * DEG;
        return new this.pc.Vec3(-Math.cos(pitch) * Math.sin(yaw), Math.sin(pitch), -Math.cos(pitch) * Math.cos(yaw));
    }

    /** The camera position for the current state. */
    position() {
        if (this.exact) return this.exact.position.clone();
        return this.target.clone().sub(this.forward().mulScalar(this.distance));
    }

    /** Leave the capture camera's exact pose: from now on the camera is yaw/pitch/distance. */
    leaveExact() {
        this.exact = null;
        this.moved += 1;
    }

    orbit(dx, dy) {
        this.leaveExact();
        this.yaw -= dx * ORBIT_DEG_PER_PX;
        this.pitch = Math.min(MAX_PITCH, Math.max(MIN_PITCH, this.pitch - dy * ORBIT_DEG_PER_PX));
    }

    /** Turn the view in place (fly mode): the camera stays, the pivot moves. */
    look(dx, dy) {
        const eye = this.position();
        this.orbit(-dx, -dy);
        this.target.copy(eye).add(this.forward().mulScalar(this.distance));
    }

    /** Move the pivot and camera across the view by a drag of (dx, dy) pixels. */
    pan(dx, dy) {
        this.leaveExact();
        const camera = this.entity.camera;
        const perPixel = (2 * this.distance * Math.tan((camera.fov * DEG) / 2)) / Math.max(1, this.element.clientHeight);
        const right = this.entity.right.clone().mulScalar(-dx * perPixel);
        const up = this.entity.up.clone().mulScalar(dy * perPixel);
        this.target.add(right).add(up);
    }

    /** Move towards (factor < 1) or away from the pivot. */
    zoom(factor) {
        this.leaveExact();
        if (this.mode === 'fly') {
            this.target.add(this.forward().mulScalar(this.scale * 0.2 * Math.log(1 / factor)));
            return;
        }
        this.distance = Math.min(this.scale * 1e3, Math.max(this.scale * 1e-3, this.distance * factor));
    }

    /** Pivot on the point under (x, y) pixels at the current pivot depth, camera unmoved. */
    pivotAt(x, y) {
        const pc = this.pc;
        const eye = this.position();
        const point = this.entity.camera.screenToWorld(x, y, this.distance, new pc.Vec3());
        const forward = point.clone().sub(eye);
        this.distance = forward.length();
        const { yaw, pitch } = anglesOf(forward);
        this.leaveExact();
        this.yaw = yaw;
        this.pitch = Math.min(MAX_PITCH, Math.max(MIN_PITCH, pitch));
        this.target.copy(point);
    }

    /** WASD/QE: move the camera and pivot together (shift: faster). */
    fly(dt) {
        const pc = this.pc;
        const k = this.keys;
        const along = (k.has('KeyW') ? 1 : 0) - (k.has('KeyS') ? 1 : 0);
        const side = (k.has('KeyD') ? 1 : 0) - (k.has('KeyA') ? 1 : 0);
        const lift = (k.has('KeyE') ? 1 : 0) - (k.has('KeyQ') ? 1 : 0);
        if (!along && !side && !lift) return;
        const speed = this.scale * FLY_RADII_PER_S * dt * (k.has('ShiftLeft') || k.has('ShiftRight') ? 4 : 1);
        const move = this.forward().mulScalar(along * speed)
            .add(this.entity.right.clone().mulScalar(side * speed))
            .add(new pc.Vec3(0, lift * speed, 0));
        this.leaveExact();
        this.target.add(move);
    }

    /** Place the camera entity (called once per frame). */
    update(dt) {
        this.fly(dt);
        if (this.exact) {
            this.entity.setPosition(this.exact.position);
            this.entity.setRotation(this.exact.rotation);
            return;
        }
        this.entity.setPosition(this.position());
        this.entity.lookAt(this.target);
    }

    /** Pointer, wheel and double-click handling on the canvas (mouse and touch alike). */
    bindPointer(element) {
        element.style.touchAction = 'none';
        element.addEventListener('contextmenu', (e) => e.preventDefault());
        element.addEventListener('pointerdown', (e) => {
            try {
                element.setPointerCapture(e.pointerId);
            } catch {
                // a pointer the browser no longer tracks: moves still arrive on the canvas
            }
            this.pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, button: e.button, shift: e.shiftKey });
        });
        const up = (e) => this.pointers.delete(e.pointerId);
        element.addEventListener('pointerup', up);
        element.addEventListener('pointercancel', up);
        element.addEventListener('pointermove', (e) => this.onMove(e));
        element.addEventListener('wheel', (e) => {
            e.preventDefault();
            this.zoom(Math.exp(e.deltaY * ZOOM_PER_WHEEL));
        }, { passive: false });
        element.addEventListener('dblclick', (e) => {
            const box = element.getBoundingClientRect();
            this.pivotAt(e.clientX - box.left, e.clientY - box.top);
        });
    }

    onMove(e) {
        const p = this.pointers.get(e.pointerId);
        if (!p) return;
        const dx = e.clientX - p.x;
        const dy = e.clientY - p.y;
        if (this.pointers.size === 2) {
            const [a, b] = [...this.pointers.values()];
            const before = Math.hypot(a.x - b.x, a.y - b.y);
            p.x = e.clientX;
            p.y = e.clientY;
            const after = Math.hypot(a.x - b.x, a.y - b.y);
            if (before > 0 && after > 0) this.zoom(before / after);
            this.pan(dx / 2, dy / 2);
            return;
        }
        p.x = e.clientX;
        p.y = e.clientY;
        if (p.button === 2 || p.button === 1 || p.shift) this.pan(dx, dy);
        else if (this.mode === 'fly') this.look(dx, dy);
        else this.orbit(dx, dy);
    }
}
