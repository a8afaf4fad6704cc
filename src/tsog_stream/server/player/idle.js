// tsog-stream web player: the controls bar steps aside while a scene plays untouched, so the
// picture has the whole window; any pointer move, touch, wheel or key brings it back.

/** Milliseconds without activity before the bar fades while playing. */
export const IDLE_MS = 3000;
const ACTIVITY = ['pointermove', 'pointerdown', 'touchstart', 'wheel', 'keydown'];

/** Mark `body` idle (the stylesheet fades the bar) after `idleMs` without activity while
 * playing; activity, a pause or the pointer over the bar clear it at once. Returns the check
 * to call every frame with whether playback is playing. */
export function fadeWhenIdle(body, bar, idleMs = IDLE_MS) {
    let last = performance.now();
    const wake = () => {
        last = performance.now();
        body.classList.remove('idle');
    };
    for (const type of ACTIVITY) window.addEventListener(type, wake, { capture: true, passive: true });
    return (playing) => {
        const idle = playing && performance.now() - last >= idleMs && !bar.matches(':hover');
        if (body.classList.contains('idle') !== idle) body.classList.toggle('idle', idle);
    };
}
