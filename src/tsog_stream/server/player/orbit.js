// tsog-stream web player: a small orbit camera (drag to turn, wheel to zoom).

const DEG = Math.PI / 180;

/** Keeps a camera entity on a sphere around a target point, driven by mouse and wheel. */
export class OrbitCamera {
    constructor(entity, element, target, distance) {
        this.entity = entity;
        this.target = target;
        this.distance = distance;
        this.yaw = 0;
        this.pitch = -15;
        this.dragging = false;
        element.addEventListener('pointerdown', (e) => {
            this.dragging = true;
            element.setPointerCapture(e.pointerId);
        });
        element.addEventListener('pointerup', () => { this.dragging = false; });
        element.addEventListener('pointermove', (e) => {
            if (!this.dragging) return;
            this.yaw -= e.movementX * 0.3;
            this.pitch = Math.min(89, Math.max(-89, this.pitch - e.movementY * 0.3));
        });
        element.addEventListener('wheel', (e) => {
            e.preventDefault();
            this.distance *= Math.exp(e.deltaY * 0.001);
        }, { passive: false });
    }

    /** Place the camera for the current yaw, pitch and distance, looking at the target. */
    update() {
        const yaw = this.yaw * DEG;
        const pitch = this.pitch * DEG;
        const d = this.distance;
        this.entity.setPosition(
            this.target.x + d * Math.cos(pitch) * Math.sin(yaw),
            this.target.y - d * Math.sin(pitch),
            this.target.z + d * Math.cos(pitch) * Math.cos(yaw),
        );
        this.entity.lookAt(this.target);
    }
}
