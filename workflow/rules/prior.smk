# The learned hair prior (strand codec + image-conditioned network), trained on generated hairstyles.
# `prior: {source: bundled}` uses the artifact committed in the package (made by this same rule with
# the default setting); `source: train` trains it here, once per setting (cached under resources/).


rule train_prior:
    output:
        weights="resources/prior/{setting}/prior.pt",
        codec="resources/prior/{setting}/codec.npz",
        record="resources/prior/{setting}/prior.json",
    params:
        cli=CLI,
        out_dir=lambda w, output: str(Path(output.weights).parent),
        seed=config["seed"],
        device=config["device"],
    wildcard_constraints:
        setting="default|tiny|render|render_large",
    log:
        "logs/train_prior/{setting}.log",
    benchmark:
        "benchmarks/rules/train_prior/{setting}.tsv"
    threads: 2
    shell:
        "{params.cli} train_prior --out-dir {params.out_dir:q} --setting {wildcards.setting:q}"
        " --seed {params.seed} --device {params.device} --threads {threads} > {log:q} 2>&1"
