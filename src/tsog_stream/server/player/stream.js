// tsog-stream web player: which chunks the playhead needs, fetched ahead and dropped behind.
// The chunk list comes from GET {chunks}?t=&horizon= (docs/http.md); each chunk is loaded by
// the engine as a gsplat asset from its ".sog" URL (the engine picks its parser by extension).

const MAX_LOADING = 4;
const RETRY_MS = 1000;

/** Chunk scheduling for one scene: asks the server, loads with the engine, unloads behind. */
export class ChunkStream {
    /**
     * @param {object} pc the PlayCanvas module
     * @param {object} app the running pc.Application
     * @param {object} config {manifest, chunks} URLs of the /v1 API
     * @param {object} manifest the parsed scene manifest
     */
    constructor(pc, app, config, manifest) {
        this.pc = pc;
        this.app = app;
        this.config = config;
        this.manifest = manifest;
        this.horizon = 2 * manifest.window_s;
        this.root = new pc.Entity('tsog-chunks');
        app.root.addChild(this.root);
        this.chunks = new Map(); // id -> {info, state: 'loading'|'ready'|'failed', asset, entity}
        this.listed = []; // the last chunk list (ids in order)
        this.listedFor = null; // [t, t + horizon] of the last list
        this.listing = null; // the chunk-list request in flight
        this.retryAt = 0; // no new list request before this (after a failure)
        this.error = null; // the last chunk-list failure
        this.bytes = 0;
        this.fetchLog = []; // every URL fetched, in order (for tests and the overlay)
    }

    /** Called every frame with the playhead: refresh the list when t leaves it, load, drop. */
    update(t) {
        const span = this.listedFor;
        const stale = !span || t < span[0] || t > span[0] + this.horizon / 2;
        if (stale && !this.listing && performance.now() >= this.retryAt) {
            this.listing = this.list(t)
                .then(() => { this.error = null; })
                .catch((err) => {
                    this.error = String(err.message ?? err);
                    this.retryAt = performance.now() + RETRY_MS;
                })
                .finally(() => { this.listing = null; });
        }
        this.loadListed();
        this.dropBehind(t);
        for (const c of this.chunks.values()) {
            if (c.entity) c.entity.enabled = c.info.start_s <= t && t <= c.info.end_s;
        }
    }

    /** Fetch the chunk list for [t, t + horizon]. */
    async list(t) {
        const url = `${this.config.chunks}?t=${t}&horizon=${this.horizon}`;
        this.fetchLog.push(url);
        const response = await fetch(url);
        if (!response.ok) throw new Error(`chunk list: HTTP ${response.status}`);
        const body = await response.json();
        this.listed = body.chunks.map((c) => c.id);
        this.listedFor = [t, t + this.horizon];
        for (const info of body.chunks) {
            if (!this.chunks.has(info.id)) this.chunks.set(info.id, { info, state: 'queued' });
        }
    }

    /** Start loading listed chunks in playback order, at most MAX_LOADING at a time. */
    loadListed() {
        let loading = [...this.chunks.values()].filter((c) => c.state === 'loading').length;
        for (const id of this.listed) {
            const c = this.chunks.get(id);
            if (loading >= MAX_LOADING) return;
            if (c && c.state === 'queued') {
                this.load(c);
                loading += 1;
            }
        }
    }

    /** Load one chunk as a gsplat asset and attach it to an entity when ready. */
    load(c) {
        const pc = this.pc;
        c.state = 'loading';
        this.fetchLog.push(c.info.url);
        const asset = new pc.Asset(`chunk-${c.info.id}`, 'gsplat', { url: c.info.url });
        c.asset = asset;
        asset.once('error', (err) => {
            c.state = 'failed';
            c.error = String(err);
        });
        asset.ready(() => {
            if (c.state !== 'loading') return; // dropped while loading
            const entity = new pc.Entity(`chunk-${c.info.id}`);
            entity.addComponent('gsplat', { asset });
            this.root.addChild(entity);
            c.entity = entity;
            c.state = 'ready';
            this.bytes += c.info.length;
        });
        this.app.assets.add(asset);
        this.app.assets.load(asset);
    }

    /** Unload chunks outside [t, t + horizon] that the current list does not hold (behind
     * the playhead, or left ahead after a jump back such as a loop). */
    dropBehind(t) {
        const keep = new Set(this.listed);
        for (const [id, c] of this.chunks) {
            const near = c.info.end_s >= t && c.info.start_s <= t + this.horizon;
            if (near || keep.has(id)) continue;
            this.unload(c);
            this.chunks.delete(id);
        }
    }

    /** Free the entity and the asset of a chunk. */
    unload(c) {
        c.state = 'dropped';
        if (c.entity) c.entity.destroy();
        if (c.asset) {
            this.app.assets.remove(c.asset);
            c.asset.unload();
        }
    }

    /** True when every listed chunk that covers t is ready. */
    covered(t) {
        if (!this.listedFor || t < this.listedFor[0] || t > this.listedFor[1]) return false;
        return this.listed.every((id) => {
            const c = this.chunks.get(id);
            const needed = c && c.info.start_s <= t && t <= c.info.end_s;
            return !needed || c.state === 'ready' || c.state === 'failed';
        });
    }

    /** Time ranges [start, end] of the loaded chunks, merged. */
    buffered() {
        const spans = [...this.chunks.values()]
            .filter((c) => c.state === 'ready')
            .map((c) => [c.info.start_s, c.info.end_s])
            .sort((a, b) => a[0] - b[0]);
        const merged = [];
        for (const [a, b] of spans) {
            const last = merged[merged.length - 1];
            if (last && a <= last[1]) last[1] = Math.max(last[1], b);
            else merged.push([a, b]);
        }
        return merged;
    }

    /** Counts for the overlay. */
    stats() {
        const all = [...this.chunks.values()];
        return {
            known: all.length,
            ready: all.filter((c) => c.state === 'ready').length,
            failed: all.filter((c) => c.state === 'failed').length,
            error: this.error,
            bytes: this.bytes,
        };
    }
}
