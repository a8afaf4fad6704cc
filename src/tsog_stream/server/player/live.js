// tsog-stream web player: following a live stream's index (docs/spec.md section 8.8). The next
// publication is asked for with ?after=SEQ: tsog serve answers as soon as there is one (the
// blocking reload, docs/http.md "Live scenes"); a static origin answers at once with the index
// it has, and is then asked again every half window. Each newer index is handed on; the
// follow stops when the event has ended or stop() is called.

/** Seconds behind the start of the newest window a viewer plays (the Python client's
 * client/live.py MARGIN_S): room for the next window's encoding and publishing. */
export const LIVE_MARGIN_S = 0.5;
/** The fastest a player plays to get back to its target distance from the edge. */
export const CATCH_UP = 1.1;
/** Seconds waited after a failed read before the next one. */
const RETRY_S = 1;

/** True while `manifest` is a live stream's index whose event goes on. */
export function isLive(manifest) {
    return manifest.live != null && !manifest.live.ended;
}

/** How far behind the edge a live stream is played: a window and the margin. */
export function liveTarget(manifest) {
    return manifest.window_s + LIVE_MARGIN_S;
}

const sleep = (seconds) => new Promise((resolve) => { setTimeout(resolve, seconds * 1000); });

/** Reads each new publication of a live index. */
export class LiveFollow {
    /**
     * @param {string} url the index's URL (its query, if any, kept)
     * @param {object} manifest the index read first
     * @param {(url: string) => Promise<object>} read fetches and checks an index
     * @param {(manifest: object) => void} onManifest hears each newer one
     */
    constructor(url, manifest, read, onManifest) {
        this.url = url;
        this.manifest = manifest;
        this.read = read;
        this.onManifest = onManifest;
        this.stopped = false;
        this.error = null;
        this.reads = 0;
    }

    /** Follow until the event ends or stop(); resolves then. */
    async run() {
        while (!this.stopped && isLive(this.manifest)) {
            const seen = this.manifest.live.sequence;
            const next = new URL(this.url);
            next.searchParams.set('after', String(seen));
            let fresh = null;
            try {
                this.reads += 1;
                fresh = await this.read(next.href);
                this.error = null;
            } catch (err) {
                this.error = err.message ?? String(err);
                await sleep(RETRY_S);
                continue;
            }
            if (this.stopped) return;
            if (fresh.live == null || fresh.live.sequence > seen || fresh.live.ended) {
                this.manifest = fresh;
                this.onManifest(fresh);
            } else {
                await sleep(fresh.window_s / 2);
            }
        }
    }

    stop() {
        this.stopped = true;
    }
}
