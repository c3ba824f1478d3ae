from bgap.runner.numerics import command

main = command("bgap.experiments.watch")
if __name__ == "__main__":
    main()
