# The built-in head model exported for other tools (OBJ, landmarks, scalp UV).


rule head_export:
    output:
        obj="resources/head/proxy-v1/head.obj",
    params:
        cli=CLI,
        out_dir=lambda w, output: str(Path(output.obj).parent),
    log:
        "logs/head_export/proxy-v1.log",
    benchmark:
        "benchmarks/rules/head_export/proxy-v1.tsv"
    shell:
        "{params.cli} head export {params.out_dir:q} > {log:q} 2>&1"
